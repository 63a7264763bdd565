"""A DataFrame's columns as a :class:`~cosim.data.trajectory.Trajectory`'s fields (for ``from_pandas``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError
from ._trajectory_checks import _TIME

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["arrays_from_frame"]


def arrays_from_frame(frame: pd.DataFrame, *, time: str | None, units: Mapping[str, str] | None,
                      roles: Mapping[str, str] | None, meta: Mapping[str, Any] | None
                      ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, str], dict[str, str], dict[str, Any]]:
    """Time, signals, units, roles and meta of `frame`, as :meth:`Trajectory.from_pandas` documents them."""
    import pandas as pd

    attrs = getattr(frame, "attrs", {}) or {}
    name = time if time is not None else (_TIME if _TIME in frame.columns else None)
    if name is not None:
        if name not in frame.columns:
            raise DataError(f"the DataFrame has no column {name!r}; columns: "
                            f"{', '.join(map(str, frame.columns))}; pass time=<the time column>")
        t, columns = frame[name], frame.drop(columns=[name])
    elif isinstance(frame.index, pd.RangeIndex) and frame.index.name is None:
        raise DataError("the DataFrame has no time column and a plain row-number index; pass "
                        "time=<the time column>, or index it by time in seconds")
    else:
        t, columns = frame.index.to_series(), frame
    if isinstance(t.dtype, pd.DatetimeTZDtype) or t.dtype.kind in "mM":
        t = (t - t.iloc[0]).dt.total_seconds()
    bad = [str(c) for c in columns.columns if columns[c].dtype.kind not in "fiub"]
    if bad or t.dtype.kind not in "fiu":
        raise DataError(f"column(s) {', '.join(bad) or 'time'} of the DataFrame are not numbers; "
                        "convert or drop them")
    data = {str(c): columns[c].to_numpy(dtype=float) for c in columns.columns}
    units = {**attrs.get("units", {}), **(units or {})}
    roles = {**attrs.get("roles", {}), **(roles or {})}
    return (t.to_numpy(dtype=float), data, {n: str(units.get(n, "")) for n in data},
            {n: roles.get(n, "output") for n in data}, dict(meta if meta is not None else attrs.get("meta", {})))
