"""One cell of the reference study's Table 1: simulate the FMU, add noise, identify, compare with clean data.

:func:`study_case` is what ``cosim reproduce paper`` runs for every (excitation, noise level, seed);
:data:`STUDY_SETTINGS` are the :class:`~cosim.identify.sindyc.SINDYc` settings it uses.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..errors import InvalidSettingError
from ..identify._settings import _check_number
from ..identify.sindyc import SINDYc
from .paper import STUDY_DT, STUDY_TABLE1, STUDY_X0

__all__ = ["STUDY_SETTINGS", "study_case"]


#: Estimator settings study_case uses unless overridden (see study_case).
STUDY_SETTINGS: dict[str, Any] = {"library": "linear", "include_constant": False, "threshold": 0.0,
                                  "differentiation": "integral",
                                  "kinematics": {"theta_m": "omega_m", "theta_L": "omega_L"},
                                  "refine": "output_error"}
_STUDY_EXCITATIONS = {"square": "square:frac=0.1,freq=1", "sine": "sine:frac=0.1,freq=5"}


def study_case(excitation: str, noise: float, seed: int, *, duration: float = 10.0, dt: float = STUDY_DT,
               initial_state: str = "estimated", fmu: Any = None, **settings: Any) -> dict[str, Any]:
    """Run one cell of the reference study: simulate the FMU, add noise, identify, compare with clean data.

    Protocol: the bundled two-mass servo FMU (default parameters) from the study's initial state
    (:data:`cosim.study.STUDY_X0`), sampled at 2257 Hz,
    driven by `excitation`; Gaussian noise of ``noise`` x (standard deviation of each clean state) added to the
    states (:meth:`Trajectory.with_noise`); :class:`SINDYc` fitted on the noisy record; the identified model
    run free over the whole record with the same inputs and compared with the **clean** states (R^2, maximum
    deviation in % of the clean peak-to-peak amplitude, MATLAB fit).

    Parameters
    ----------
    excitation : str
        ``"square"`` (``square:frac=0.1,freq=1``: +-10 % of the 5000 N m maximum torque, 1 Hz: long enough
        half-periods (0.5 s) for the rigid-body motion to build up, and its edges excite the 17.8 Hz
        resonance), ``"sine"`` (``sine:frac=0.1,freq=5``, the study's 5 Hz sine), or any signal spec for
        ``Tm``.
    noise : float
        Noise level, e.g. 0.1 for 10 %.
    seed : int
        Seed of the noise.
    duration : float
        Record length in s (rounded to whole steps). Default 10 s (22570 samples): the initial 4 rad twist
        rings down in about 3 s (time constant 0.75 s) and the longer tail pins down the slow rigid-body
        mode and the input gain.
    dt : float
        Sampling step.
    initial_state : {"estimated", "known"}
        ``"estimated"`` (default; what a user of measured data has): the refinement estimates the initial
        state from the noisy data and the free run starts there (without refinement: the first noisy
        sample). ``"known"``: the study's ``STUDY_X0`` is given to the fit (kept fixed by the
        refinement) and the free run starts there.
    fmu : path, optional
        FMU to use (default the bundled two-mass servo, built on first use).
    **settings
        :class:`SINDYc` settings overriding :data:`STUDY_SETTINGS`.

    Returns
    -------
    dict
        ``excitation``, ``noise``, ``seed``, ``duration``, ``samples``, ``settings``, ``states``,
        ``r2``, ``max_dev_pct``, ``nrmse`` (state -> value), ``study_max_dev_pct`` (Table 1's row for this
        level, when it has one), ``coef`` (list of rows), ``terms``, ``equations``, ``status`` of the free
        run, ``fit_seconds``, ``threshold``, ``refinement`` (cost, stages) and ``x0``.

    Examples
    --------
    >>> result = study_case("sine", 0.0, 0, duration=1.0)
    >>> min(result["r2"].values()) > 0.9999
    True
    """
    from ..data.simulation import simulate as simulate_fmu
    from ..identify.metrics import max_deviation_pct, nrmse_fit_pct, r2
    from ..plant.build import build_fmu

    if initial_state not in ("estimated", "known"):
        raise InvalidSettingError(f"initial_state must be 'estimated' or 'known', got {initial_state!r}")
    _check_number("noise", noise, low=0.0)
    _check_number("duration", duration, low=0.0, allow_zero=False)
    spec = _STUDY_EXCITATIONS.get(excitation, excitation)
    steps = max(int(round(duration / dt)), 1)
    clean = simulate_fmu(fmu or build_fmu(), {"Tm": spec}, duration=steps * dt, dt=dt, start=STUDY_X0)
    data = clean.with_noise(float(noise), seed=int(seed)) if noise > 0 else clean
    used = {**STUDY_SETTINGS, **settings}
    states = list(STUDY_X0)
    started = time.perf_counter()
    known = STUDY_X0 if initial_state == "known" else None
    est = SINDYc(**used).fit(data, states=states, inputs=["Tm"], x0=known)
    seconds = time.perf_counter() - started
    model = est.model_
    truth = np.asarray(clean[states], dtype=float)
    if initial_state == "known":
        x0 = np.array([STUDY_X0[s] for s in states])
    else:
        x0 = np.array(model.meta["x0"][0]) if "x0" in model.meta else np.asarray(data[states])[0]
    u = np.asarray(data[list(model.inputs)], dtype=float)[:-1]
    sim = model.simulate(x0, u, dt=dt)
    pred = sim.states
    if not sim.ok:
        pred = np.where(np.isfinite(pred), pred, 1e300)
    r2v, dev, fit = r2(truth, pred), max_deviation_pct(truth, pred), nrmse_fit_pct(truth, pred)
    table = STUDY_TABLE1.get(round(float(noise), 6))
    return {
        "excitation": spec, "noise": float(noise), "seed": int(seed), "duration": steps * dt, "dt": dt,
        "samples": len(clean), "settings": {**used, "initial_state": initial_state}, "states": states,
        "r2": dict(zip(states, np.atleast_1d(r2v).tolist(), strict=True)),
        "max_dev_pct": dict(zip(states, np.atleast_1d(dev).tolist(), strict=True)),
        "nrmse": dict(zip(states, np.atleast_1d(fit).tolist(), strict=True)),
        "study_max_dev_pct": dict(table) if table else None,
        "coef": model.coef.tolist(), "terms": list(model.terms), "equations": model.equations(),
        "status": sim.status, "fit_seconds": seconds, "threshold": est.threshold_,
        "refinement": {k: v for k, v in model.meta.get("refinement", {}).items() if k != "std_error"},
        "x0": x0.tolist(), "stable": model.meta.get("stable"),
    }
