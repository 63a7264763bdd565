"""PNG plot of a closed-loop run (:class:`~cosim.loop.closed_loop.ClosedLoopResult`).
(``cosim validate --report`` and the demo draw these; ``tests/test_validation.py`` checks them.)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..figures import pyplot, save_figure

__all__ = ["plot_closed_loop"]


def plot_closed_loop(result: Any, path: str | os.PathLike, *, title: str | None = None) -> Path:
    """Plot a closed-loop run as PNG: each tracked output with its reference (FMU and model), each manipulated
    input with the controller's limits, and the controller's compute time per call against the sample period.

    Parameters
    ----------
    result : cosim.loop.closed_loop.ClosedLoopResult
    path : path-like
        The PNG file to write.
    title : str, optional
    """
    plt = pyplot()
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
