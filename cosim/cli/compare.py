"""``cosim compare``: a model's free-run (or K-step-ahead) prediction of a data file, scored per state."""

from __future__ import annotations

import click

from ..errors import UnknownVariableError
from ._command import _emit, _friendly, _names
from ._data_options import data_options, derive_option, read_records
from ._outputs import check_outputs

__all__ = ["compare_command"]


@click.command("compare")
@click.argument("model_path", metavar="MODEL.json")
@click.argument("data_path", metavar="DATA")
@click.option("--horizon", type=click.IntRange(1, None), default=None, metavar="K",
              help="Predict each sample K samples ahead from the measured state (default: the free run).")
@click.option("--x0", "initial_state", type=click.Choice(["estimate", "measured", "model"]), default="estimate",
              show_default=True, help="The free run's initial state: estimated from the data (as MATLAB's "
              "compare), the first sample, or the one the model was identified with.")
@click.option("--state", "states", default=None, metavar="A,B,...",
              help="State columns (default: the model's state names; NAME=EXPR for an expression).")
@click.option("--input", "inputs", default=None, metavar="U,...",
              help="Input columns (default: the model's input names; NAME=EXPR, e.g. force=35.15*vir).")
@data_options
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="Write a PNG: each state measured and predicted, the error under it.")
@click.option("--json", "as_json", is_flag=True,
              help='Print {"fit_pct": {...}, "nrmse_pct": {...}, "r2": {...}, "horizon", "x0", "samples"}.')
@_friendly
def compare_command(model_path: str, data_path: str, horizon: int | None, initial_state: str, states: str | None,
                    inputs: str | None, derive: str | None, derive_window: int | None, time_column: str | None,
                    resample: bool, plot_path: str | None, as_json: bool) -> None:
    """Predict DATA with MODEL and score each state: fit_pct (MATLAB's NRMSE fit, 100 is perfect), nrmse_pct
    (the error, 0 is perfect) and r2.

    \b
    Example:
      cosim compare model.json data.csv --json
      cosim compare model.json run2.csv --horizon 20 --plot compare.png
    """
    from ..identify.compare import compare
    from ..identify.model import IdentifiedModel

    check_outputs({"--plot": [plot_path]}, {"--plot": (".png", ".pdf", ".svg")})
    model = IdentifiedModel.load(model_path)
    derived = derive_option(derive)
    state_specs = _names(states, "--state") if states else list(model.states)
    input_specs = _names(inputs, "--input") if inputs else list(model.inputs)
    notes = []
    try:
        [data] = read_records([data_path], states=state_specs, inputs=input_specs, derive=derived,
                              time=time_column, derive_window=derive_window, resample=resample)
    except UnknownVariableError:
        # the model's own velocities differentiated from positions when it was identified: derive them the same way
        recorded = {v: p for v, p in ((model.meta.get("data") or {}).get("derived_velocities") or {}).items()
                    if v in state_specs and v not in derived}
        if not recorded:
            raise
        derived = {**derived, **recorded}
        [data] = read_records([data_path], states=state_specs, inputs=input_specs, derive=derived,
                              time=time_column, derive_window=derive_window, resample=resample)
        notes.append("derived " + ", ".join(f"{v} from {p}" for v, p in recorded.items()) + " as when the model "
                     "was identified (--derive " + ",".join(f"{v}={p}" for v, p in recorded.items()) + ")")
    result = compare(model, data, horizon=horizon, x0=initial_state)
    payload = result.to_dict()
    if notes:
        payload["notes"] = notes
    if plot_path:
        result.plot(plot_path)
        payload["plot"] = plot_path
    what = "free run" if horizon is None else f"{horizon}-step-ahead prediction"
    lines = [f"{model_path} against {data_path} ({what}, {len(result.measured)} samples):"]
    lines += [f"  {n}: fit {result.fit_pct[n]:.2f} %  NRMSE {result.nrmse_pct[n]:.2f} %  R2 {result.r2[n]:.6g}"
              for n in result.fit_pct]
    lines += [f"note: {n}" for n in notes]
    if plot_path:
        lines.append(f"wrote {plot_path}")
    _emit(as_json, payload, "\n".join(lines))
