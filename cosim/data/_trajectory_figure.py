"""The figure of a :class:`~cosim.data.trajectory.Trajectory` (for ``Trajectory.plot`` and
:func:`~cosim.data.plots.plot_trajectory`): every signal against time, one panel each, with units; other runs
drawn over it, and their error under each panel when asked."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..figures import COLOURS, FONT_SIZE, axis_label, new_figure

if TYPE_CHECKING:
    from .trajectory import Trajectory

__all__ = ["trajectory_figure"]

#: Colours of further runs that name none (after the roles' colours, so none repeats a role).
_SPARE = ("C4", "C5", "C8", "C9", "C7")


def _ylabel(name: str, unit: str) -> str:
    return axis_label(name, unit).replace(" [", "\n[", 1)


def _values_on(other: Trajectory, name: str, time: np.ndarray) -> np.ndarray:
    """`other`'s `name` at the sample times `time` (interpolated if its samples differ; NaN outside them)."""
    if len(other) == len(time) and np.array_equal(other.time, time):
        return np.asarray(other[name], dtype=float)
    return np.interp(time, other.time, other[name], left=np.nan, right=np.nan)


def trajectory_figure(
    traj: Trajectory,
    *,
    others: Sequence[tuple[Any, ...]] = (),
    label: str = "data",
    title: str | None = None,
    errors: bool = False,
    colour: str | None = None,
) -> Any:
    """The matplotlib Figure :func:`~cosim.data.plots.plot_trajectory` draws (see there for the arguments).

    `traj` is drawn thin and on top (measured data), the other runs thicker under it. A signal that is zero
    throughout in every run is left out (the title says so); a signal another run holds identically is drawn
    once (the panel says so). The error panels hold `traj` minus each other run.
    """
    runs = []
    for i, entry in enumerate(others):
        other_label, other = entry[0], entry[1]
        runs.append((other_label, other, entry[2] if len(entry) > 2 else _SPARE[i % len(_SPARE)]))
    colour = colour or COLOURS["measured"]
    names = list(traj.inputs) + [n for n in traj.names if n not in traj.inputs]
    zero = [n for n in names if not np.any(traj[n]) and all(not np.any(o[n]) for _, o, _ in runs if n in o.names)]
    names = [n for n in names if n not in zero] or names[:1]
    with_error = {n: errors and n not in traj.inputs and any(n in o.names for _, o, _ in runs) for n in names}
    ratios = [r for n in names for r in ([3, 1] if with_error[n] else [3])]
    fig = new_figure(figsize=(9, 0.55 * sum(ratios) + 1.2), layout="constrained")
    axes = fig.subplots(len(ratios), 1, sharex=True, squeeze=False, gridspec_kw={"height_ratios": ratios})[:, 0]
    panel = iter(axes)
    for name in names:
        ax = next(panel)
        unit = traj.units[traj.names.index(name)]
        is_input = name in traj.inputs
        draw = ax.step if is_input else ax.plot
        kwargs = {"where": "post"} if is_input else {}
        draw(traj.time, traj[name], lw=0.7, color=colour, zorder=3, label=label, **kwargs)
        same = []
        for other_label, other, other_colour in runs:
            if name not in other.names:
                continue
            values = _values_on(other, name, traj.time)
            if np.array_equal(values, traj[name]):
                same.append(str(other_label))
                continue
            (ax.step if is_input else ax.plot)(traj.time, values, lw=1.4, color=other_colour, alpha=0.9, zorder=2,
                                               label=other_label, **kwargs)
        if same:
            ax.set_title(f"{name}: the same in {', '.join(same)} (drawn once)", loc="right", fontsize=FONT_SIZE,
                         color="0.3", pad=3)
        ax.set_ylabel(_ylabel(name, unit), fontsize=FONT_SIZE)
        ax.grid(alpha=0.3)
        if with_error[name]:
            err = next(panel)
            for other_label, other, other_colour in runs:
                if name in other.names:
                    err.plot(traj.time, traj[name] - _values_on(other, name, traj.time), lw=0.8,
                             color=other_colour, label=other_label)
            err.axhline(0.0, color=COLOURS["reference"], lw=0.5)
            err.set_ylabel(_ylabel("error", unit), fontsize=FONT_SIZE)
            err.grid(alpha=0.3)
    axes[-1].set_xlabel("time [s]", fontsize=FONT_SIZE + 1)
    if runs:
        handles = [next(line for ax in axes for line in ax.get_lines() if line.get_label() == lab)
                   for lab in [label, *(str(r[0]) for r in runs)]
                   if any(line.get_label() == lab for ax in axes for line in ax.get_lines())]
        fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 4), fontsize=FONT_SIZE)
    note = f"{', '.join(zero)} {'is' if len(zero) == 1 else 'are'} zero throughout: not drawn" if zero else ""
    if title or note:
        fig.suptitle("\n".join(t for t in (title, note) if t), fontsize=FONT_SIZE + 2)
    return fig
