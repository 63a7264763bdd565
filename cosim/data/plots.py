"""Plot of a :class:`~cosim.data.trajectory.Trajectory`: every signal against time, as a matplotlib Figure.

Examples
--------
>>> import numpy as np, tempfile, pathlib
>>> from cosim import Trajectory
>>> t = np.linspace(0, 1, 101)
>>> traj = Trajectory.from_arrays(t, {"u": np.sin(t), "y": np.cos(t)}, units={"y": "rad"},
...                               roles={"u": "input", "y": "output"})
>>> fig = plot_trajectory(traj, path=pathlib.Path(tempfile.mkdtemp()) / "traj.png")
>>> [ax.get_ylabel() for ax in fig.axes]
['u', 'y\\n[rad]']
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..figures import finish
from ._trajectory_figure import trajectory_figure
from .trajectory import Trajectory

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = ["plot_trajectory", "trajectory_figure"]


def plot_trajectory(
    traj: Trajectory,
    path: str | os.PathLike | None = None,
    *,
    others: Sequence[tuple[Any, ...]] = (),
    label: str = "data",
    title: str | None = None,
    errors: bool = False,
    colour: str | None = None,
) -> matplotlib.figure.Figure:
    """Plot every signal of `traj` against time, one panel each (inputs first, as steps), with units.

    `traj` is drawn thin, dark and on top (:data:`~cosim.figures.COLOURS` ``"measured"``); the `others` thicker
    under it. A signal zero throughout every run is left out (the title says so); a signal another run holds
    identically is drawn once (the panel says so).

    Parameters
    ----------
    traj : Trajectory
        What to plot.
    path : path-like, optional
        Write the figure there as PNG too.
    others : sequence of (label, Trajectory) or (label, Trajectory, colour)
        Further runs drawn over the first, signal by signal (a clean run under noisy data, a model's free
        run); without a colour each gets one no role uses.
    label, title : str
        Legend label of `traj`, and the figure title.
    errors : bool
        Under each output's panel, a panel of `traj` minus each of the `others` (for models against data).
    colour : str, optional
        Colour of `traj` (default: the measured data's).

    Returns
    -------
    matplotlib.figure.Figure
    """
    return finish(trajectory_figure(traj, others=others, label=label, title=title, errors=errors, colour=colour),
                  path)
