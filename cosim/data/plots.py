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

from ..figures import save_figure
from ._trajectory_figure import trajectory_figure
from .trajectory import Trajectory

__all__ = ["plot_trajectory", "trajectory_figure"]


def plot_trajectory(
    traj: Trajectory,
    path: str | os.PathLike,
    *,
    others: Sequence[tuple[str, Trajectory]] = (),
    label: str = "data",
    title: str | None = None,
) -> Path:
    """Plot every signal of `traj` against time, one panel each (inputs first, as steps), as PNG.

    :func:`trajectory_figure` draws it; this writes it to `path` and returns the path.

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
    return save_figure(trajectory_figure(traj, others=others, label=label, title=title), path)
