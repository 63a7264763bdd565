"""PNG plot of a :class:`~cosim.data.trajectory.Trajectory`: every signal against time.

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

from ..figures import pyplot, save_figure
from .trajectory import Trajectory

__all__ = ["plot_trajectory"]


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
    plt = pyplot()
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
