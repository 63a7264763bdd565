"""PNG figures: matplotlib on the Agg backend (no screen needed), written atomically.

Every room draws its own results (:mod:`cosim.data.plots`, :mod:`cosim.loop.plots`, the diagnosis and the
study); they all take pyplot from :func:`pyplot` and write through :func:`save_figure`, so matplotlib loads
only when a figure is drawn.

Examples
--------
>>> import tempfile, pathlib
>>> plt = pyplot()
>>> fig, ax = plt.subplots()
>>> _ = ax.plot([0, 1], [0, 1])
>>> save_figure(fig, pathlib.Path(tempfile.mkdtemp()) / "line.png").suffix
'.png'
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .files import atomic_output

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = ["new_figure", "pyplot", "save_figure"]


def new_figure(**kwargs: Any) -> matplotlib.figure.Figure:
    """A matplotlib Figure outside pyplot: no backend switched, nothing to close, shown inline by Jupyter when
    returned, written by :func:`save_figure` (keyword arguments go to ``Figure``)."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files, not windows), imported on first use."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: matplotlib.figure.Figure, path: str | os.PathLike, *, dpi: int = 110,
                close: bool = True) -> Path:
    """Save `fig` as PNG atomically, close it in pyplot (unless `close` is false), and return the path."""
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    if close and fig.canvas.manager is not None:  # a pyplot figure; new_figure's have no manager
        pyplot().close(fig)
    return Path(path)
