"""The options every command that reads measured data shares, read one way: ``--state``, ``--input``,
``--derive``, ``--derive-window``, ``--time``, ``--resample``, and the records they give.

* ``--state A,B`` and ``--input U,...``: columns of the file, or named expressions of its variables
  (``force=35.15*vir``; a ``.mat`` matrix's column ``pos=data[:,2]``);
* ``--derive POS`` adds the velocity ``POS_dot`` differentiated from ``POS``; ``--derive VEL=POS`` names it
  ``VEL``; several are comma-separated;
* ``--time COLUMN``: the time column in seconds (default ``t``, else ``time``);
* CSV, Parquet and ``.mat`` files alike (:func:`cosim.data.datafile.load_data`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import click

from ..errors import InvalidSettingError
from ._command import _names

__all__ = ["data_options", "derive_option", "read_records"]


def data_options(func: Any) -> Any:
    """Decorate a command with ``--derive``, ``--derive-window``, ``--time`` and ``--resample``."""
    options = [
        click.option("--derive", default=None, metavar="POS|VEL=POS,...",
                     help="Velocities not measured: POS adds POS_dot differentiated from POS (VEL=POS names it "
                          "VEL), e.g. --derive qm or --derive omega_m=theta_m."),
        click.option("--derive-window", "derive_window", default=None, type=click.IntRange(3), metavar="N",
                     help="Savitzky-Golay window of --derive in samples (default: chosen from the data's noise "
                          "and bandwidth)."),
        click.option("--time", "time_column", default=None, metavar="COLUMN",
                     help="Time column in seconds (default t, else time; .mat: also data[:,0])."),
        click.option("--resample", is_flag=True,
                     help="Interpolate a non-uniform time onto a uniform grid instead of refusing it."),
    ]
    for option in reversed(options):
        func = option(func)
    return func


def derive_option(text: str | None) -> dict[str, str]:
    """``--derive``: ``"qm,omega=theta"`` -> {"qm_dot": "qm", "omega": "theta"} (velocity -> position)."""
    out: dict[str, str] = {}
    for item in _names(text, "--derive") if text else []:
        vel, sep, pos = item.partition("=")
        vel, pos = (vel.strip(), pos.strip()) if sep else (f"{item}_dot", item)
        if not vel or not pos:
            raise InvalidSettingError(f"--derive takes POS or VEL=POS, got {item!r}")
        out[vel] = pos
    return out


def read_records(paths: Sequence[str], *, states: Sequence[str], inputs: Sequence[str], derive: dict[str, str],
                 time: str | None, derive_window: int | None = None, resample: bool = False,
                 differentiate: bool = True) -> list[Any]:
    """Each file as a Trajectory of `states` (roles ``state``) then `inputs` (``input``; ``NAME=EXPR`` allowed).

    With `differentiate` the velocities of `derive` are computed here; without it their positions are read
    for the caller to differentiate (``SINDYc(velocities=...)``).
    """
    from ..data.datafile import load_data
    from ..data.trajectory import Trajectory

    state_specs = [s for s in states if s not in derive]
    state_names = [s.partition("=")[0].strip() for s in states]
    for vel, pos in derive.items():
        if vel not in state_names:
            given = "--derive " + (pos if vel == f"{pos}_dot" else f"{vel}={pos}")
            raise InvalidSettingError(f"{given} adds the velocity {vel}, which is not in --state "
                                      f"{','.join(state_names)}: add it, --state {','.join([*state_names, vel])}")
    input_names = [s.partition("=")[0].strip() for s in inputs]
    sources = [p for p in dict.fromkeys(derive.values()) if p not in state_names]
    columns = list(dict.fromkeys([*state_specs, *sources, *inputs]))
    rename = {f"{pos}_dot": vel for vel, pos in derive.items()} if differentiate else {}
    records = []
    for path in paths:
        # roles now, so that the record's checks know its inputs (a constant input is refused)
        data = load_data(path, time=time, columns=columns, derive=list(dict.fromkeys(derive.values()))
                         if differentiate else (), derive_window=derive_window, resample=resample,
                         roles={**dict.fromkeys((n for n in state_names if n not in derive), "state"),
                                **dict.fromkeys(input_names, "input")})
        if any(old != new for old, new in rename.items()):
            meta = dict(data.meta)  # the velocities under their given names (cosim.data.derived_velocities)
            meta["data_file"] = {**meta["data_file"], "derivatives": {**meta["data_file"]["derivatives"],
                                                                     "velocities": dict(derive)}}
            data = Trajectory.from_arrays(data.time, {rename.get(n, n): data[n] for n in data.names},
                                          units={rename.get(n, n): data.units[i] for i, n in enumerate(data.names)},
                                          meta=meta)
        wanted = [*state_names, *input_names] if differentiate else [
            *[n for n in state_names if n not in derive], *sources, *input_names]
        data = data.select(list(dict.fromkeys(wanted)))
        records.append(data.with_roles(states=[n for n in data.names if n not in input_names],
                                       inputs=[n for n in data.names if n in input_names]))
    return records
