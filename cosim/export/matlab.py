"""MATLAB export: the state-space form of a model as a ``.mat`` file that ``ss(...)`` builds in MATLAB.

* :func:`export_mat` - ``A, B, C, D, dt``, the signal names as cell arrays of char, the operating point and the
  identified equations (the matrices of :func:`~cosim.export.statespace.to_statespace`).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from ..files import atomic_output
from ..identify.model import IdentifiedModel
from .statespace import CONSTANT_INPUT, label_name, to_statespace

__all__ = ["export_mat"]


def _cell(strings: Iterable[str]) -> np.ndarray:
    strings = list(strings)
    cell = np.empty((len(strings), 1), dtype=object)
    for i, s in enumerate(strings):
        cell[i, 0] = str(s)
    return cell


def export_mat(model: IdentifiedModel, path: str | os.PathLike, *, dt: float | None = None,
               operating_point: Any = None, constant: str = "input", name: str | None = None) -> Path:
    """Write the state-space model to a MATLAB ``.mat`` file (atomically).

    Variables: ``A, B, C, D``; ``dt`` (0 for continuous); ``StateName, InputName, OutputName`` (cell arrays of
    char: ``ss(A, B, C, D, dt, 'StateName', StateName, 'InputName', InputName, 'OutputName', OutputName)``
    builds it in MATLAB; use ``ss(A, B, C, D)`` for dt = 0); ``x_op, u_op`` (the point the signals are
    deviations from); ``Equations`` (cell of char, the identified equations); ``ConstantInput`` (``'const'``
    when the constant is an input held at 1, else empty); ``Notes`` (char). The signal names are written as the
    model writes them (``mass.s``, ``x[2]``): they are values in cells, and the file's own variable names are
    only the fixed ones above, so any name fits.

    Parameters
    ----------
    model : IdentifiedModel
    path : path-like
        The ``.mat`` file.
    dt, operating_point, constant, name
        As in :func:`to_statespace`.

    Returns
    -------
    pathlib.Path

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib, scipy.io
    >>> from cosim.identify.model import IdentifiedModel
    >>> model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.0, 2.0]]))
    >>> path = export_mat(model, pathlib.Path(tempfile.mkdtemp()) / "model.mat")
    >>> scipy.io.loadmat(path)["B"].tolist()
    [[2.0]]
    """
    import scipy.io

    sys = to_statespace(model, dt=dt, operating_point=operating_point, constant=constant, name=name)
    has_const = CONSTANT_INPUT in sys.input_labels and CONSTANT_INPUT not in model.inputs
    notes = ("dx/dt = A x + B u" if sys.dt == 0 else "x[k+1] = A x[k] + B u[k] (zero-order hold)") + \
        ", y = C x + D u; y are the states; states and inputs are deviations from x_op, u_op" + \
        ("; hold the input 'const' at 1 (it carries the constant term)" if has_const else "")
    data = {
        "A": sys.A, "B": sys.B, "C": sys.C, "D": sys.D, "dt": float(sys.dt),
        "StateName": _cell(map(label_name, sys.state_labels)), "InputName": _cell(map(label_name, sys.input_labels)),
        "OutputName": _cell(map(label_name, sys.output_labels)),
        "x_op": sys.operating_point.x.reshape(-1, 1), "u_op": sys.operating_point.u.reshape(-1, 1),
        "Equations": _cell(model.equations(precision=10)),
        "ConstantInput": CONSTANT_INPUT if has_const else "",
        "Notes": notes,
    }
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        scipy.io.savemat(fh, data, do_compression=True)
    return Path(path)
