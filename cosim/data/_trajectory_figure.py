"""The figure of a :class:`~cosim.data.trajectory.Trajectory` (for ``Trajectory.plot`` and
:func:`~cosim.data.plots.plot_trajectory`): every signal against time, one panel each, with units."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..figures import new_figure

if TYPE_CHECKING:
    from .trajectory import Trajectory

__all__ = ["trajectory_figure"]


def trajectory_figure(
    traj: Trajectory,
    *,
    others: Sequence[tuple[str, Trajectory]] = (),
    label: str = "data",
    title: str | None = None,
) -> Any:
    """The matplotlib Figure :func:`~cosim.data.plots.plot_trajectory` writes (see there for the arguments)."""
    names = list(traj.inputs) + [n for n in traj.names if n not in traj.inputs]
    fig = new_figure(figsize=(9, 1.7 * len(names) + 0.8))
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)
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
    return fig
