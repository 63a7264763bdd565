"""What a record can show, for the search: its band (:func:`record_band`) and the effect selection checked
against it.

The nuisance grids come from the record (:class:`~cosim.diagnose._record_band.RecordBand`: the screen's sample
time, length and noise levels, with the free run's signals): an effect the record cannot show at a place is
not tried there. An effect given a fixed nuisance (``"cogging:periods=120"``) is tried at that value only, and a
value outside the band the record shows is refused before any search (:func:`check_effect_selection`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..errors import InvalidSettingError
from ..identify.model import IdentifiedModel
from . import _record_band as rb
from ._record_band import RecordBand
from .effects import EFFECTS, Attachment, Effect, EffectSelection, Roles, effect_selection
from .screening import OutputErrorScreen, noise_level


def record_band(screen: OutputErrorScreen) -> RecordBand:
    """What the screen's record can show: its sample time, length, the states' noise levels and the positions'
    visible bands (through the model), with the ranges of the free run's signals (the nuisance grids are scaled
    on the noise-free free run)."""
    return RecordBand.of(screen.free_run, screen.dt, dict(zip(screen.model.states, map(float, screen.sigma),
                                                                strict=True)), model=screen.model,
                         measured={s: screen.columns[s] for s in screen.measured})


def check_effect_selection(selection: str | Sequence[str] | EffectSelection, model: IdentifiedModel,
                           columns: Mapping[str, np.ndarray], dt: float,
                           noise: Mapping[str, float] | None = None) -> EffectSelection:
    """The parsed selection, or a one-line :class:`~cosim.errors.InvalidSettingError` when a fixed nuisance value
    (``"cogging:periods=120"``) lies outside what the data can show at every place the effect attaches to in
    `model` (a period above the record's Nyquist band or with fewer than two periods over the travel, a delay
    longer than the record allows...). Call it before any screening; `columns` are the measured data, `noise` the
    states' noise levels where known (else estimated from the data)."""
    parsed = effect_selection(selection)
    if not parsed.fixed:
        return parsed
    levels = {s: float(noise[s]) if noise and s in noise else noise_level(np.asarray(columns[s], dtype=float))
              for s in model.states if s in columns}
    motion = {**columns, **{s: _smoothed(np.asarray(columns[s], dtype=float), dt) for s in model.states
                            if s in columns}}
    _check_fixed(parsed, Roles.of(model), motion, RecordBand.of(motion, dt, levels, model=model))
    return parsed


def _smoothed(x: np.ndarray, dt: float) -> np.ndarray:
    """`x` smoothed as its derivative is (Savitzky-Golay, the window chosen from its noise and band): the band's
    speeds are then the motion's, not its noise's (at 1 % noise on a position sampled at 1 kHz, central
    differences gave 15 times the speed, and refused a cogging's periods the record shows)."""
    from scipy.signal import savgol_filter

    from ..data.derivatives import savgol_window

    if x.size < 16:
        return x
    window = min(savgol_window(x, dt), x.size - (x.size % 2 == 0))
    return savgol_filter(x, window, 3) if window > 4 else x


def _check_fixed(selection: EffectSelection, roles: Roles, data: Mapping[str, np.ndarray], band: RecordBand) -> None:
    for name, value in selection.fixed.items():
        effect = EFFECTS[name]
        item = f"{name}:{effect.nuisance}={value:.12g}"
        places = effect.attachments(roles)
        if not places:
            raise InvalidSettingError(f"{item}: the model has no {effect.attaches_to.replace('_', ' ')} for "
                                      f"{name} to act on")
        if any(effect.admits(value, a, data, band) for a in places):
            continue
        bands = "; ".join(_describe(effect, a, data, band) for a in places)
        raise InvalidSettingError(f"{item} is outside what these data can show ({bands}); give a value in that "
                                  f"band, or {name!r} alone to search it, or record the plant over a wider range "
                                  f"or at a faster sampling")


def _describe(effect: Effect, attachment: Attachment, data: Mapping[str, np.ndarray], band: RecordBand) -> str:
    span = effect.nuisance_span(attachment, data, band)
    where = f"on {attachment.label}"
    sampled = f"{1 / band.dt:.4g} Hz sampling" if band.dt else "no sample time"
    if effect.unit == "periods":
        signal = effect.signal(attachment, data)
        speed = rb.typical_speed(rb.speed_of(signal, band))
        facts = (f"range {np.ptp(signal):.3g}, speed {speed:.3g}/s at the {rb.SPEED_PERCENTILE:.0f}th percentile, "
                 f"{sampled}")
    else:
        facts = f"{band.samples} samples, {sampled}"
    if span is None:
        return f"{where} none ({facts})"
    return f"{where} {effect.nuisance} {span[0]:.4g} to {span[1]:.4g} ({facts})"
