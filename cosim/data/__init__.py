"""The data room: sampled records and where they come from.

* :mod:`~cosim.data.trajectory` - :class:`Trajectory`, a record of named signals with units and roles, its CSV
  and Parquet files;
* :mod:`~cosim.data.datafile` - :func:`load_data` for measured files (CSV, Parquet, ``.mat``) with column
  expressions, :func:`check_excitation`, and what a file holds before it is read (:func:`file_variables`,
  :func:`time_column`: ``t`` when a file has one and no ``time``, else ``time``);
* :mod:`~cosim.data.derivatives` - derivative estimation (:func:`differentiate`, :data:`DERIVATIVE_METHODS`);
* :mod:`~cosim.data.decimation` - a signal's band above its noise (:func:`signal_bandwidth`) and a record at a
  lower rate (:func:`decimate`);
* :mod:`~cosim.data.signals` - excitation signals (square, sine, PRBS, chirp, multisine...) and their specs;
* :mod:`~cosim.data.simulation` - :func:`simulate`: an FMU driven by signals, recorded as a Trajectory;
* :mod:`~cosim.data.plots` - :func:`plot_trajectory`.

Modules whose names start with ``_`` hold the code of the public modules above, split by job (the signal
classes, factories and spec form; a trajectory's checks and files; load_data's column expressions and file
readers); import from the public modules or from ``cosim.data``.

Imports the plant room and the foundation only.
"""

from __future__ import annotations

from .datafile import MIN_SAMPLES, UNIFORM_RTOL, check_excitation, file_variables, load_data, time_column
from .decimation import decimate, signal_bandwidth
from .derivatives import DERIVATIVE_METHODS, differentiate
from .plots import plot_trajectory
from .signals import (
    SIGNAL_KINDS,
    Chirp,
    Constant,
    Multisine,
    Prbs,
    ScaledSignal,
    Signal,
    SignalKind,
    SignalSum,
    SineWave,
    SquareWave,
    Step,
    chirp,
    constant,
    multisine,
    parse_signal,
    prbs,
    signal_kinds_help,
    sine,
    square,
    step,
)
from .simulation import InputSpec, sample_input, simulate
from .trajectory import ROLES, Trajectory

__all__ = [
    "Chirp", "Constant", "DERIVATIVE_METHODS", "InputSpec", "MIN_SAMPLES", "Multisine", "Prbs", "ROLES",
    "SIGNAL_KINDS", "ScaledSignal", "Signal", "SignalKind", "SignalSum", "SineWave", "SquareWave", "Step",
    "Trajectory", "UNIFORM_RTOL", "check_excitation", "chirp", "constant", "decimate", "differentiate",
    "file_variables", "load_data",
    "multisine", "parse_signal", "plot_trajectory", "prbs", "sample_input", "signal_bandwidth", "signal_kinds_help",
    "simulate", "sine", "square", "step", "time_column",
]
