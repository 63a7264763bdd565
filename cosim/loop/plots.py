"""Plot of a closed-loop run (:class:`~cosim.loop.closed_loop.ClosedLoopResult`), as a matplotlib Figure.
(``cosim validate --report`` and the demo draw these; ``tests/test_figures.py`` checks them.)
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from ..figures import COLOURS, FONT_SIZE, axis_label, finish, new_figure

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = ["plot_closed_loop"]


def _unit(traj: Any, name: str) -> str:
    return traj.units[traj.names.index(name)] if name in traj.names else ""


def plot_closed_loop(result: Any, path: str | os.PathLike | None = None, *,
                     title: str | None = None) -> matplotlib.figure.Figure:
    """Plot a closed-loop run: each tracked output with its reference (FMU and model) and, under it, the FMU
    minus the model; each manipulated input with the controller's limits; and the controller's compute time per
    call against the sample period.

    The FMU is drawn thin, dark and on top, the model loop thicker and green under it (the colours of
    :data:`cosim.figures.COLOURS`); axes carry the signals' units where the run knows them.

    Parameters
    ----------
    result : cosim.loop.closed_loop.ClosedLoopResult
    path : path-like, optional
        Write the figure there as PNG too.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    traj, model = result.fmu, result.model
    has_model = model is not None and len(model) > 1
    ratios = [r for _ in result.tracked for r in ([3, 1] if has_model else [3])] + [3] * len(result.inputs) + [2]
    fig = new_figure(figsize=(9, 0.55 * sum(ratios) + 1.0), layout="constrained")
    axes = fig.subplots(len(ratios), 1, sharex=True, squeeze=False, gridspec_kw={"height_ratios": ratios})[:, 0]
    panel = iter(axes)
    for name in result.tracked:
        ax, unit = next(panel), _unit(traj, name)
        ax.plot(traj.time, traj[f"r_{name}"], color=COLOURS["reference"], ls="--", lw=0.9, label="reference")
        ax.plot(traj.time, traj[name], color=COLOURS["fmu"], lw=0.9, zorder=3, label="FMU")
        if has_model:
            ax.plot(model.time, model[name], color=COLOURS["model"], lw=2.0, alpha=0.8, zorder=2,
                    label="design model")
        ax.set_ylabel(axis_label(name, unit), fontsize=FONT_SIZE)
        ax.legend(fontsize=FONT_SIZE, loc="lower right")
        if has_model:
            err = next(panel)
            k = min(len(model), len(traj))
            err.plot(traj.time[:k], traj[name][:k] - model[name][:k], color=COLOURS["model"], lw=0.9)
            err.axhline(0.0, color=COLOURS["reference"], lw=0.5)
            err.set_ylabel(axis_label("FMU −\nmodel", unit), fontsize=FONT_SIZE)
    for j, name in enumerate(result.inputs):
        ax, unit = next(panel), _unit(traj, name)
        ax.step(traj.time, traj[name], where="post", color=COLOURS["fmu"], lw=0.9, zorder=3, label="FMU loop")
        if has_model and name in model.names:
            ax.step(model.time, model[name], where="post", color=COLOURS["model"], lw=2.0, alpha=0.8, zorder=2,
                    label="model loop")
        for limit in (result.limits[0][j], result.limits[1][j]):
            if np.isfinite(limit):
                ax.axhline(limit, color=COLOURS["limit"], lw=0.8, ls=":")
        ax.set_ylabel(axis_label(name, unit) + "\n(control)", fontsize=FONT_SIZE)
        ax.legend(fontsize=FONT_SIZE, loc="upper right")
    ax = next(panel)
    ct = result.compute_time * 1e6
    ax.plot(traj.time[:len(ct)], ct, ".", ms=1.5, color=COLOURS["measured"])
    ax.axhline(result.dt * 1e6, color=COLOURS["limit"], lw=0.8, ls=":", label=f"sample period {result.dt * 1e6:.0f} µs")
    ax.set_yscale("log")
    ax.set_ylabel("compute time\n[µs/call]", fontsize=FONT_SIZE)
    ax.legend(fontsize=FONT_SIZE, loc="upper right")
    for a in axes:
        a.grid(alpha=0.3)
        for event in result.events:
            a.axvline(event["time"], color=COLOURS["event"], lw=0.8, alpha=0.7)
    axes[-1].set_xlabel("time [s]", fontsize=FONT_SIZE + 1)
    if title:
        fig.suptitle(title, fontsize=FONT_SIZE + 2)
    return finish(fig, path)
