"""PNG plots of results, written atomically (matplotlib, Agg backend: no screen needed).

Examples
--------
>>> import numpy as np, tempfile, pathlib
>>> from cosim import Trajectory
>>> t = np.linspace(0, 1, 101)
>>> traj = Trajectory.from_arrays(t, {"u": np.sin(t), "y": np.cos(t)}, roles={"u": "input", "y": "output"})
>>> plot_trajectory(traj, pathlib.Path(tempfile.mkdtemp()) / "traj.png").suffix
'.png'
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)

from .files import atomic_output  # noqa: E402
from .trajectory import Trajectory  # noqa: E402

__all__ = ["plot_closed_loop", "plot_trajectory", "save_figure"]


def save_figure(fig: matplotlib.figure.Figure, path: str | os.PathLike, *, dpi: int = 110) -> Path:
    """Save `fig` as PNG atomically, close it, and return the path."""
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    plt.close(fig)
    return Path(path)


def plot_trajectory(
    traj: Trajectory,
    path: str | os.PathLike,
    *,
    others: Sequence[tuple[str, Trajectory]] = (),
    label: str = "data",
    title: str | None = None,
) -> Path:
    """Plot every signal of `traj` against time, one panel each (inputs first, as steps), as PNG.

    Parameters
    ----------
    traj : Trajectory
        What to plot.
    path : path-like
        The PNG file to write.
    others : sequence of (label, Trajectory)
        Further trajectories drawn over the first, signal by signal (for instance a clean run under noisy data).
    label, title : str
        Legend label of `traj`, and the figure title.
    """
    names = list(traj.inputs) + [n for n in traj.names if n not in traj.inputs]
    fig, axes = plt.subplots(len(names), 1, sharex=True, figsize=(9, 1.7 * len(names) + 0.8), squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        unit = traj.units[traj.names.index(name)]
        draw = ax.step if name in traj.inputs else ax.plot
        kwargs = {"where": "post"} if name in traj.inputs else {}
        draw(traj.time, traj[name], lw=0.8, label=label, **kwargs)
        for other_label, other in others:
            if name in other.names:
                ax.plot(other.time, other[name], lw=0.8, label=other_label)
        ax.set_ylabel(f"{name}\n[{unit}]" if unit else name, fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    if others:
        axes[0, 0].legend(fontsize=8, loc="upper right")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_closed_loop(result: Any, path: str | os.PathLike, *, title: str | None = None) -> Path:
    """Plot a closed-loop run as PNG: each tracked output with its reference (FMU and model), each manipulated
    input with the controller's limits, and the controller's compute time per call against the sample period.

    Parameters
    ----------
    result : cosim.closed_loop.ClosedLoopResult
    path : path-like
        The PNG file to write.
    title : str, optional
    """
    traj, model = result.fmu, result.model
    rows = len(result.tracked) + len(result.inputs) + 1
    fig, axes = plt.subplots(rows, 1, sharex=True, figsize=(9, 2.0 * rows + 0.8), squeeze=False)
    axes = axes[:, 0]
    for ax, name in zip(axes, result.tracked, strict=False):
        ax.plot(traj.time, traj[f"r_{name}"], "k--", lw=0.9, label="reference")
        ax.plot(traj.time, traj[name], lw=1.0, label="FMU")
        if model is not None:
            ax.plot(model.time, model[name], lw=0.9, alpha=0.8, label="design model")
        ax.set_ylabel(name, fontsize=8)
        ax.legend(fontsize=8, loc="lower right")
    for j, name in enumerate(result.inputs):
        ax = axes[len(result.tracked) + j]
        ax.step(traj.time, traj[name], where="post", lw=0.9, label="FMU loop")
        if model is not None:
            ax.step(model.time, model[name], where="post", lw=0.8, alpha=0.8, label="model loop")
        for limit in (result.limits[0][j], result.limits[1][j]):
            if np.isfinite(limit):
                ax.axhline(limit, color="r", lw=0.7, ls=":")
        ax.set_ylabel(f"{name}\n(control effort)", fontsize=8)
        ax.legend(fontsize=8, loc="upper right")
    ax = axes[-1]
    ct = result.compute_time * 1e6
    ax.plot(traj.time[:len(ct)], ct, ".", ms=1.5)
    ax.axhline(result.dt * 1e6, color="r", lw=0.8, ls=":", label=f"sample period {result.dt * 1e6:.0f} µs")
    ax.set_yscale("log")
    ax.set_ylabel("compute\n[µs/call]", fontsize=8)
    ax.legend(fontsize=8, loc="upper right")
    for a in axes:
        a.grid(alpha=0.3)
        for event in result.events:
            a.axvline(event["time"], color="m", lw=0.8, alpha=0.6)
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path)
