"""Figures: matplotlib Figures built outside pyplot, one colour per role, written as PNG atomically when asked.

Every room draws its own results (:mod:`cosim.data.plots`, :mod:`cosim.loop.plots`, the diagnosis and the
study). Each plot function builds its Figure with :func:`new_figure` (no pyplot: a notebook's backend is left
alone, there is nothing to close, Jupyter shows the returned Figure inline) and returns it; it writes a PNG
through :func:`save_figure` only when given a path (:func:`finish`). matplotlib loads only when a figure is
drawn.

So that a reader learns the colours once, every figure draws a role in the colour :data:`COLOURS` gives it:
measured data (and the FMU) dark grey, thin and on top; the model before a diagnosis orange, after it blue;
a single model green; references black and dashed; limits red.

Examples
--------
>>> import tempfile, pathlib
>>> fig = new_figure()
>>> ax = fig.subplots()
>>> _ = ax.plot([0, 1], [0, 1], color=COLOURS["measured"])
>>> save_figure(fig, pathlib.Path(tempfile.mkdtemp()) / "line.png").suffix
'.png'
>>> axis_label("Tm", "N.m")
'Tm [N m]'
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .files import atomic_output

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = ["COLOURS", "FONT_SIZE", "axis_label", "binned_mean", "finish", "new_figure", "pyplot", "save_figure"]

#: One colour per role, in every figure: measured data and the FMU dark grey (thin, on top), the model before a
#: diagnosis (the linear model) orange, the model after it (the diagnosed model) blue, a single model (the
#: identified or design model) green, a second run (say, without the effect) purple, references black (dashed),
#: limits and confidence bounds red, events pink.
COLOURS: dict[str, str] = {
    "measured": "0.2",
    "fmu": "0.2",
    "model": "C2",
    "before": "C1",
    "after": "C0",
    "other": "C4",
    "reference": "k",
    "limit": "C3",
    "event": "C6",
}

#: Font size of axis labels, legends and panel titles (tick labels use matplotlib's default, 10).
FONT_SIZE = 9


def new_figure(**kwargs: Any) -> matplotlib.figure.Figure:
    """A matplotlib Figure outside pyplot: no backend switched, nothing to close, shown inline by Jupyter when
    returned, written by :func:`save_figure`.

    Parameters
    ----------
    **kwargs
        Passed to ``matplotlib.figure.Figure`` (``figsize``, ``layout``...).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files, not windows), imported on first use.

    Returns
    -------
    module
        ``matplotlib.pyplot``. Kept for scripts that want it; cosim's own figures use :func:`new_figure`.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: matplotlib.figure.Figure, path: str | os.PathLike, *, dpi: int = 110,
                close: bool = True) -> Path:
    """Save `fig` as PNG atomically and return the path.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : path-like
        The PNG file to write.
    dpi : int
        Resolution.
    close : bool
        Close a pyplot figure after writing it (figures of :func:`new_figure` have nothing to close).

    Returns
    -------
    pathlib.Path
    """
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    if close and fig.canvas.manager is not None:  # a pyplot figure; new_figure's have no manager
        pyplot().close(fig)
    return Path(path)


def finish(fig: matplotlib.figure.Figure, path: str | os.PathLike | None = None) -> matplotlib.figure.Figure:
    """The end of every plot function: write `fig` as PNG if `path` is given, and return it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : path-like, optional

    Returns
    -------
    matplotlib.figure.Figure
        `fig`.
    """
    if path is not None:
        save_figure(fig, path, close=False)
    return fig


def axis_label(name: str, unit: str = "") -> str:
    """``"name [unit]"`` (just `name` without a unit); a product written ``N.m`` reads ``N m``.

    Parameters
    ----------
    name, unit : str

    Returns
    -------
    str
    """
    unit = re.sub(r"(?<=[A-Za-z])\.(?=[A-Za-z])", " ", unit or "")
    return f"{name} [{unit}]" if unit else name


def binned_mean(x: np.ndarray, y: np.ndarray, bins: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                         np.ndarray]:
    """`y` averaged in `bins` equal bins of `x`: what a scatter cloud hides (a step at zero speed) shows.

    Parameters
    ----------
    x, y : numpy.ndarray
        Paired samples (non-finite pairs are dropped).
    bins : int
        Number of equal-width bins over the range of `x`.

    Returns
    -------
    centre, mean, std, count : numpy.ndarray
        Per bin holding at least two samples: its centre, the mean and standard deviation of `y` in it, and
        how many samples it holds.

    Examples
    --------
    >>> centre, mean, std, count = binned_mean(np.array([0.0, 0.1, 0.9, 1.0]), np.array([1.0, 3.0, 5.0, 7.0]),
    ...                                        bins=2)
    >>> mean.tolist(), count.tolist()
    ([2.0, 6.0], [2, 2])
    """
    x, y = np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if x.size == 0 or np.ptp(x) == 0:
        empty = np.zeros(0)
        return empty, empty, empty, np.zeros(0, dtype=int)
    edges = np.linspace(x.min(), x.max(), bins + 1)
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    count = np.bincount(which, minlength=bins)
    mean = np.bincount(which, weights=y, minlength=bins) / np.maximum(count, 1)
    spread = np.bincount(which, weights=(y - mean[which]) ** 2, minlength=bins) / np.maximum(count, 1)
    full = count >= 2
    return 0.5 * (edges[:-1] + edges[1:])[full], mean[full], np.sqrt(spread[full]), count[full]
