"""Does `cosim diagnose`'s default path generalise? Records from an independent simulator, scored against the truth.

Records come from ``benchmarks/independent_plants.py`` (scipy solve_ivp, its own equations: single mass and
two-mass plants over three decades of size, 200 Hz-5 kHz, 0.2-5 % noise, multisine / PRBS / steps / closed
loop, positions-only records, every catalogued effect sized to 2-20x the noise, a quarter with none, some
with two). Each record is run through the default command lines only, as subprocesses, with no per-case
option (positions-only records add ``--derive``, which names the data's columns):

(a) ``cosim diagnose DATA.csv --state S --input U [--derive POS] --json -o model_after_a.json``
(b) ``cosim identify DATA.csv --state S --input U [--derive VEL=POS] -o model.json`` then
    ``cosim diagnose DATA.csv --state S --input U [--derive POS] --model model.json --json -o model_after_b.json``

Scored per record and path: the right effect named first (no effect named, for a record without one); a false
claim (an effect named that the record lacks); the relative error of each found effect's main parameter
(cosim's name -> the simulator's: Fc, Fs, viscous_asymmetry -> d, half_width, width, level, amplitude_<row> ->
cogging's amplitude or gravity's G, offset_<row> -> F0, delay_s (or delay_samples * dt) -> delay_s, and
cubic_stiffness's coef_<row> / the row's input gain in the diagnosed model, sign turned, -> k3; forces are in
the input's units in both); the held-out error, when an effect is accepted: the free run of the model before and
after on the record's held-out twin (same plant and effects, another excitation), from the twin's true initial
state (the simulator's, at rest: the same for both models; a delayed input copy is 0 before t = 0, as the
plant saw it), as NRMSE % against the twin's noise-free states,
averaged over the model's states; "worse" when after exceeds before by more than 0.1 %. The model before is
model.json for path (b); for path (a), whose CLI does not write it, the same default fit is made in-process
(SINDYc as cosim/cli/diagnose.py calls it). When an ``offset`` is named (the base model's constant, kept), the
model before is that model refitted on the train record without the constant of its dynamic rows, the model the
diagnosis judged the offset against (the model before has the constant too). Wall time: the CLI calls of a
path. Failures (a non-zero exit, a time-out, unreadable JSON) are counted and listed; a failed record scores as
not right.

Results go to benchmarks/results/diagnosis_generalization.json and .md.

Run:  python benchmarks/bench_diagnosis_generalization.py [--n 200] [--slice 0:10] [--jobs 2] [--out DIR]
      [--max-samples 30000] [--paths a,b] [--cosim PATH_TO_cosim]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_plants as ip  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
#: The issue's thresholds.
THRESHOLDS = {"right_first_pct": (">=", 90.0), "false_claims_pct": ("<=", 5.0),
              "median_param_error_pct": ("<=", 10.0), "accepted_worse_heldout": ("<=", 0),
              "median_time_s": ("<=", 10.0)}
WORSE_TOLERANCE = 1e-3  # held-out NRMSE after > before * (1 + this): the effect made it worse


# ---------------------------------------------------------------------------------------------- records
def prepare(index: int, data_dir: Path, max_samples: int) -> Path:
    """The folder of record `index`, generated unless already there from this version of the generator
    (truth.json is written last)."""
    folder = data_dir / f"record_{index:04d}_{max_samples}"
    truth = folder / "truth.json"
    if not truth.is_file() or json.loads(truth.read_text()).get("generator") != ip.GENERATOR_VERSION:
        ip.make_record(index, max_samples=max_samples).write(folder)
    return folder


def commands(folder: Path, cli: dict, cosim: str) -> dict[str, list[list[str]]]:
    """The command lines of paths (a) and (b) for a record."""
    data = str(folder / "train.csv")
    common = ["--state", ",".join(cli["states"]), "--input", cli["input"]]
    derive_diag = ["--derive", ",".join(cli["derive"])] if cli["derive"] else []
    derive_id = ["--derive", ",".join(f"{p}_dot={p}" for p in cli["derive"])] if cli["derive"] else []
    return {
        "a": [[cosim, "diagnose", data, *common, *derive_diag, "--json", "-o", str(folder / "model_after_a.json")]],
        "b": [[cosim, "identify", data, *common, *derive_id, "-o", str(folder / "model.json")],
              [cosim, "diagnose", data, *common, *derive_diag, "--model", str(folder / "model.json"), "--json",
               "-o", str(folder / "model_after_b.json")]],
    }


def _run(argv: list[str], timeout: float) -> tuple[int, str, str, float]:
    start = time.perf_counter()
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=_env())
        return proc.returncode, proc.stdout, proc.stderr, time.perf_counter() - start
    except subprocess.TimeoutExpired:
        return -9, "", f"timed out after {timeout:.0f} s", time.perf_counter() - start


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("MPLBACKEND", "Agg")
    return env


# ---------------------------------------------------------------------------------------------- scoring
def _pick(params: dict[str, float], prefix: str, row: str | None) -> float:
    """cosim's per-row parameter ``<prefix><row>`` (the truth's row first, else the first such)."""
    if row is not None and f"{prefix}{row}" in params:
        return float(params[f"{prefix}{row}"])
    keys = [k for k in params if k.startswith(prefix) and not k.endswith("_accel")]
    return float(params[keys[0]]) if keys else math.nan


def input_gain(model_path: Path, row: str, input_name: str) -> float:
    """The coefficient of the input in `row` of a saved model (its delayed copies included)."""
    from cosim.identify.model import IdentifiedModel

    model = IdentifiedModel.load(model_path)
    i = model.states.index(row)
    terms = list(model.terms)
    return float(sum(model.coef[i, terms.index(t)] for t in terms
                     if t == input_name or t.startswith(f"{input_name}_delayed_")))


def estimate(truth_effect: dict, found: dict, cli: dict, dt: float, model_after: Path | None) -> float:
    """cosim's value of the truth effect's main parameter, in the simulator's units (see the module notes)."""
    p = found.get("parameters", {})
    name = truth_effect["name"]
    row = ip.cosim_name(cli, truth_effect["row"]) if truth_effect.get("row") else None
    direct = {"coulomb_friction": "Fc", "stribeck": "Fs", "viscous_asymmetry": "viscous_asymmetry",
              "backlash": "half_width", "deadzone": "width", "saturation": "level"}
    if name in direct:
        return float(p.get(direct[name], math.nan))
    if name in ("cogging", "gravity"):
        return _pick(p, "amplitude_", row)
    if name == "offset":
        return _pick(p, "offset_", row)
    if name == "delay":
        return float(p["delay_s"]) if "delay_s" in p else float(p.get("delay_samples", math.nan)) * dt
    if name == "cubic_stiffness":
        rows = [k[len("coef_"):] for k in p if k.startswith("coef_")]
        motor = ip.cosim_name(cli, "omega_m")
        r = motor if motor in rows else (rows[0] if rows else None)
        if r is None or model_after is None or not model_after.is_file():
            return math.nan
        gain = input_gain(model_after, r, cli["input"])
        sign = -1.0 if r == motor else 1.0  # k3 tw^3 leaves the motor's row and enters the load's
        return sign * float(p[f"coef_{r}"]) / gain if gain else math.nan
    return math.nan


def score(spec: dict, cli: dict, effects: list[dict], model_after: Path | None) -> dict[str, Any]:
    """Right first, false claim, right place, parameter errors for one path's named effects."""
    truth = spec["effects"]
    names = {e["name"] for e in truth}
    named = [e["name"] for e in effects]
    out: dict[str, Any] = {"named": named, "attached": [e.get("attached_to") for e in effects]}
    if not truth:
        out["right_first"] = not named
    else:
        out["right_first"] = bool(named) and named[0] in names
    out["false_claim"] = any(n not in names for n in named)
    places = {e["name"]: ip.cosim_name(cli, e["at"]) for e in truth}
    out["right_place"] = bool(named) and named[0] in places and effects[0].get("attached_to") == places[named[0]] \
        if truth else not named
    errors = {}
    for t in truth:
        match = next((e for e in effects if e["name"] == t["name"]), None)
        if match is None:
            continue
        try:
            est = estimate(t, match, cli, spec["dt"], model_after)
        except Exception as exc:  # a mapping failure is reported, not fatal
            out.setdefault("notes", []).append(f"parameter of {t['name']}: {exc!r}")
            est = math.nan
        true = float(t["main_value"])
        errors[t["name"]] = {"true": true, "estimate": est,
                             "rel_error_pct": abs(est - true) / abs(true) * 100 if math.isfinite(est) else math.inf}
    out["param_errors"] = errors
    return out


# ---------------------------------------------------------------------------------------------- held-out error
def heldout_nrmse(model_path_or_model: Any, folder: Path, spec: dict, cli: dict) -> float:
    """Free-run NRMSE % of a model on the held-out twin, against its noise-free states, from its true start."""
    from cosim.identify.model import IdentifiedModel

    model = model_path_or_model if isinstance(model_path_or_model, IdentifiedModel) else \
        IdentifiedModel.load(model_path_or_model)
    clean = dict(np.load(folder / "heldout_clean.npz"))
    truth_of = {v: k for k, v in cli["velocity_names"].items()}  # cosim's velocity name -> simulator's
    cols = []
    for name in model.inputs:
        head, sep, tail = name.rpartition("_delayed_")
        if sep and tail.isdigit():  # a delayed copy of the input; before t = 0 the input was 0 (plant at rest)
            k = int(tail)
            src = clean[head]
            cols.append(np.concatenate([np.zeros(k), src[:len(src) - k]]))
        else:
            cols.append(clean[name])
    inputs = np.column_stack(cols)[:-1] if cols else None
    true_states = [clean[truth_of.get(s, s)] for s in model.states]
    x0 = [float(x[0]) for x in true_states]
    sim = model.simulate(x0, inputs, dt=spec["dt"])
    if not sim.ok or not np.all(np.isfinite(sim.states)):
        return math.inf
    errs = [float(np.sqrt(np.mean((sim.states[:, i] - x) ** 2)) / max(float(np.std(x)), 1e-300))
            for i, x in enumerate(true_states)]
    return 100.0 * float(np.mean(errs))


def _train_data(folder: Path, cli: dict):
    """The train record as ``cosim diagnose`` reads it (derived velocities too)."""
    from cosim.data.datafile import load_data

    states, derived = cli["states"], cli["derive"]
    derived_names = {f"{p}_dot" for p in derived}
    columns = [s for s in states if s not in derived_names] + [cli["input"]]
    roles = {**dict.fromkeys(states, "state"), cli["input"]: "input"}
    return load_data(folder / "train.csv", columns=columns, roles=roles, derive=derived).select(
        [*states, cli["input"]])


def _model_before_a(folder: Path, cli: dict):
    """Path (a)'s model before, fitted in-process as ``cosim diagnose`` fits it without --model."""
    from cosim.diagnose.diagnosis import BASE_SETTINGS  # the settings `cosim diagnose` identifies with
    from cosim.identify.sindyc import SINDYc

    return SINDYc(**BASE_SETTINGS).fit(_train_data(folder, cli), states=cli["states"],
                                       inputs=[cli["input"]]).model_


def _without_constant(model: Any, folder: Path, cli: dict):
    """`model` refitted on the train record (output error) without the constant of its dynamic rows.

    An ``offset`` finding is the base model's constant kept (``cosim diagnose`` identifies with a constant and
    judges it last, against the model refitted without it): compared with the model before, which has the
    constant too, it would measure refit drift only. This is the model it is judged against.
    """
    from cosim.diagnose.effects import Roles
    from cosim.diagnose.screening import output_error_fit
    from cosim.identify.model import IdentifiedModel

    model = model if isinstance(model, IdentifiedModel) else IdentifiedModel.load(model)
    if "1" not in model.terms:
        return model
    coef = model.coef.copy()
    for row in Roles.of(model).dynamic_rows:
        coef[model.states.index(row), model.terms.index("1")] = 0.0
    reduced = IdentifiedModel(states=model.states, inputs=model.inputs, terms=model.terms, coef=coef, dt=model.dt,
                              meta=model.meta)
    data = _train_data(folder, cli)
    return output_error_fit(reduced, {n: data[n] for n in data.names}, data.dt)[0]


# ---------------------------------------------------------------------------------------------- one record
def nonlinear_part(spec: dict, cli: dict, folder: Path) -> dict[str, float]:
    """Per rated effect, its contribution over the noise times the share of its force no linear model takes
    up (:func:`independent_plants.nonlinear_share`, on the record's noise-free run, replayed from its written
    commands): roughly what of it the record can show beyond a change of the linear model."""
    import pandas as pd

    u = pd.read_csv(folder / "train.csv")[cli["input"]].to_numpy(dtype=float)
    share = ip.nonlinear_share(spec, ip.replay(spec, u))
    return {e["name"]: e["ratio"] * share[e["name"]] for e in spec["effects"] if e["name"] in share}


#: An effect whose force a linear model takes up to this share (RMS) is a linear change over the record (the
#: generator draws such an effect again; records of its first version had them).
LINEAR_SHARE = ip.LINEAR_SHARE


def linear_equivalent(spec: dict, nonlinear: dict[str, float]) -> str | None:
    """Why no model could tell the record's effect from the linear model, or None.

    When every effect is rated and a linear model takes up its whole force (a saturation or dead zone under
    an input of one magnitude is a gain change; a Coulomb friction above every command, smoothed, a viscous
    one), the record can only answer "no effect"; it is counted as the issue defines (a miss) and listed
    apart.
    """
    if not spec["effects"] or len(nonlinear) < len(spec["effects"]):
        return None
    if all(nonlinear[e["name"]] <= LINEAR_SHARE * e["ratio"] for e in spec["effects"]):
        return "a linear model takes up the whole of the effect's force over this record"
    return None


def run_record(index: int, data_dir: str, max_samples: int, paths: tuple[str, ...], cosim: str,
               timeout: float, heldout: bool = True) -> dict[str, Any]:
    """Generate (or reuse) record `index`, run the paths, score them. Never raises: errors are in the row."""
    row: dict[str, Any] = {"index": index, "failures": []}
    try:
        start = time.perf_counter()
        folder = prepare(index, Path(data_dir), max_samples)
        row["generate_s"] = time.perf_counter() - start
        truth = json.loads((folder / "truth.json").read_text())
        spec, cli = truth["spec"], truth["cli"]
        row["truth"] = [{k: e[k] for k in ("name", "at", "main", "main_value", "ratio")} for e in spec["effects"]]
        row["record"] = {k: spec[k] for k in ("samples", "rate_hz", "duration_s", "excitation", "positions_only",
                                              "noise_frac", "combined_ratio")}
        row["record"]["plant"] = spec["plant"]["kind"]
        row["record"]["nonlinear"] = nonlinear_part(spec, cli, folder)
        row["record"]["linear_equivalent"] = linear_equivalent(spec, row["record"]["nonlinear"])
    except Exception as exc:
        row["failures"].append({"path": "generate", "error": f"{type(exc).__name__}: {exc}",
                                "traceback": traceback.format_exc(limit=3)})
        return row
    cmds = commands(folder, cli, cosim)
    for path in paths:
        res: dict[str, Any] = {"commands": [" ".join(c) for c in cmds[path]], "seconds": 0.0}
        row[path] = res
        out = ""
        ok = True
        for argv in cmds[path]:
            rc, out, err, secs = _run(argv, timeout)
            res["seconds"] += secs
            if rc != 0:
                ok = False
                last = (err.strip().splitlines() or ["(no message)"])[-1]
                row["failures"].append({"path": path, "command": " ".join(argv), "exit": rc, "error": last})
                break
        res["ok"] = ok
        if not ok:
            continue
        try:
            payload = json.loads(out)
        except json.JSONDecodeError as exc:
            res["ok"] = False
            row["failures"].append({"path": path, "command": " ".join(cmds[path][-1]), "exit": 0,
                                    "error": f"unreadable JSON: {exc}"})
            continue
        effects = payload.get("effects", [])
        # with the evidence each was accepted on (held-out figures, size, BIC), to study the claims afterwards
        res["effects"] = [{k: e.get(k) for k in ("name", "attached_to", "parameters", "explained", "delta_bic")}
                          for e in effects]
        res["before_nrmse_pct"] = payload.get("before", {}).get("nrmse_pct")
        res["after_nrmse_pct"] = payload.get("after", {}).get("nrmse_pct")
        after_path = folder / f"model_after_{path}.json"
        res.update(score(spec, cli, effects, after_path))
        if effects and heldout:
            try:
                res.update(heldout_figures(path, [e["name"] for e in effects], folder, spec, cli))
            except Exception as exc:
                row["failures"].append({"path": path, "command": "held-out simulation",
                                        "error": f"{type(exc).__name__}: {exc}"})
    return row


def heldout_figures(path: str, named: list[str], folder: Path, spec: dict, cli: dict, before: Any = None) -> dict:
    """The held-out NRMSE % before and after a path's findings (its model after, as written in `folder`; the model
    before: `before`, or the path's own), and whether they made it worse."""
    before_model = before or (folder / "model.json" if path == "b" else _model_before_a(folder, cli))
    if "offset" in named:  # against the model without the constant
        before_model = _without_constant(before_model, folder, cli)
    b = heldout_nrmse(before_model, folder, spec, cli)
    a = heldout_nrmse(folder / f"model_after_{path}.json", folder, spec, cli)
    # a model before that diverges on the twin cannot be made worse
    return {"heldout_before_pct": b, "heldout_after_pct": a,
            "heldout_worse": bool(math.isfinite(b) and a > b * (1 + WORSE_TOLERANCE))}


# ---------------------------------------------------------------------------------------------- summary
def _pct(values: list[bool]) -> float:
    return 100.0 * sum(values) / len(values) if values else math.nan


def _median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else math.nan


def summarize(rows: list[dict], path: str) -> dict[str, Any]:
    """Per effect and overall figures of one path (failed records count as not right, not as false claims)."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        names = [e["name"] for e in r.get("truth", [])] or ["none"]
        for name in names:
            groups.setdefault(name, []).append(r)

    def figures(group: list[dict], effect: str | None) -> dict[str, Any]:
        res = [r.get(path, {}) for r in group]
        errors = []
        for x in res:
            for name, e in x.get("param_errors", {}).items():
                if effect is None or name == effect:
                    errors.append(e["rel_error_pct"])
        times = [x["seconds"] for x in res if x.get("ok")]
        return {"records": len(group), "failed": sum(not x.get("ok") for x in res),
                "right_first_pct": _pct([bool(x.get("right_first")) for x in res]),
                "right_place_pct": _pct([bool(x.get("right_place")) for x in res]),
                "false_claims_pct": _pct([bool(x.get("false_claim")) for x in res]),
                "param_errors": len(errors), "median_param_error_pct": _median(errors),
                "accepted_worse_heldout": sum(bool(x.get("heldout_worse")) for x in res),
                "median_time_s": _median(times)}

    per_effect = {name: figures(groups[name], None if name == "none" else name)
                  for name in sorted(groups, key=lambda n: (n == "none", n))}
    overall = figures(rows, None)
    overall["pass"] = {k: _meets(overall[k], *THRESHOLDS[k]) for k in THRESHOLDS}
    showable = [r for r in rows if not r.get("record", {}).get("linear_equivalent")]
    overall["showable"] = {"records": len(showable),
                           "right_first_pct": _pct([bool(r.get(path, {}).get("right_first")) for r in showable]),
                           "false_claims_pct": _pct([bool(r.get(path, {}).get("false_claim")) for r in showable])}
    overall["by_nonlinear_part"] = _by_nonlinear_part(rows, path)
    return {"per_effect": per_effect, "overall": overall}


#: Bin edges of an effect's non-linear part over the noise (:func:`nonlinear_part`, the largest of a record's).
NONLINEAR_BINS = (0.0, 0.5, 1.0, 2.0, 4.0, math.inf)


def _by_nonlinear_part(rows: list[dict], path: str) -> list[dict]:
    """Named right first and false claims per bin of the records' non-linear part (rated effects only)."""
    out = []
    for lo, hi in zip(NONLINEAR_BINS[:-1], NONLINEAR_BINS[1:], strict=True):
        group = [r for r in rows if r.get("record", {}).get("nonlinear")
                 and lo <= max(r["record"]["nonlinear"].values()) < hi]
        res = [r.get(path, {}) for r in group]
        out.append({"from": lo, "to": hi, "records": len(group),
                    "right_first_pct": _pct([bool(x.get("right_first")) for x in res]),
                    "false_claims_pct": _pct([bool(x.get("false_claim")) for x in res])})
    return out


def _meets(value: float, op: str, limit: float) -> bool:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return value >= limit if op == ">=" else value <= limit


def markdown(result: dict[str, Any]) -> str:
    lines = [f"# Diagnosis generalisation: {result['records']} records from an independent simulator", "",
             f"Records {result['slice']}, at most {result['max_samples']} samples each; cosim: `{result['cosim']}`; "
             f"{result['jobs']} jobs; {result['wall_s']:.0f} s in all. Generated by "
             f"benchmarks/independent_plants.py version {ip.GENERATOR_VERSION} (scipy solve_ivp, its own "
             "equations).", ""]
    if result.get("note"):
        lines += [result["note"], ""]
    for path, title in (("a", "(a) `cosim diagnose DATA --state .. --input .. --json -o ..` (identifies first)"),
                        ("b", "(b) `cosim identify ... -o model.json`, then `cosim diagnose ... --model model.json`")):
        if path not in result["summary"]:
            continue
        s = result["summary"][path]
        lines += [f"## {title}", "",
                  "| effect | records | failed | named right first % | right place % | false claims % "
                  "| median parameter error % (n) | accepted, worse held-out | median time s |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for name, f in [*s["per_effect"].items(), ("**overall**", s["overall"])]:
            lines.append(f"| {name} | {f['records']} | {f['failed']} | {f['right_first_pct']:.0f} | "
                         f"{f['right_place_pct']:.0f} | {f['false_claims_pct']:.0f} | "
                         f"{f['median_param_error_pct']:.1f} ({f['param_errors']}) | "
                         f"{f['accepted_worse_heldout']} | {f['median_time_s']:.1f} |")
        o = s["overall"]
        lines += ["", "| overall | measured | issue's threshold | met |", "| --- | --- | --- | --- |"]
        labels = {"right_first_pct": "named right first %", "false_claims_pct": "false claims %",
                  "median_param_error_pct": "median parameter error %",
                  "accepted_worse_heldout": "accepted effects raising the held-out error",
                  "median_time_s": "median time s"}
        for key, (op, limit) in THRESHOLDS.items():
            lines.append(f"| {labels[key]} | {o[key]:.3g} | {op} {limit:g} | {'yes' if o['pass'][key] else 'NO'} |")
        if "showable" in o:
            apart = [r["index"] for r in result["rows"] if r.get("record", {}).get("linear_equivalent")]
            lines += ["", f"Apart from the {len(apart)} records whose effect a linear model takes up whole over the "
                      f"record (a saturation or dead zone under an input of one magnitude, a Coulomb friction "
                      f"above every command: records "
                      f"{', '.join(map(str, apart)) or 'none'}), {o['showable']['records']} records: named right "
                      f"first {o['showable']['right_first_pct']:.3g} %, false claims "
                      f"{o['showable']['false_claims_pct']:.3g} %. The table and the verdicts above count every "
                      "record, as the issue does."]
        if o.get("by_nonlinear_part"):
            lines += ["", "By the effect's non-linear part: its contribution over the noise times the share of its "
                      "force no linear model takes up (the record's noise-free run; offsets and delays not rated). "
                      "Below about 1 the record shows little of it beyond a change of the linear model.", "",
                      "| non-linear part x noise | records | named right first % | false claims % |",
                      "| --- | --- | --- | --- |"]
            lines += [f"| {b['from']:g}-{b['to']:g} | {b['records']} | {b['right_first_pct']:.0f} | "
                      f"{b['false_claims_pct']:.0f} |" for b in o["by_nonlinear_part"]]
        lines.append("")
    fails = [(r["index"], f) for r in result["rows"] for f in r.get("failures", [])]
    lines += [f"## Failures ({len(fails)})", ""]
    lines += [f"- record {i} ({f['path']}): `{f.get('command', '')}` -> exit {f.get('exit', '-')}: {f['error']}"
              for i, f in fails] or ["none"]
    lines += ["", "Two-effect records count in both effects' rows. A record without an effect is 'named right' "
              "when nothing is named. Held-out: free run from the twin's true initial state, NRMSE % against its "
              "noise-free states; 'worse' when after > before x 1.001.", ""]
    return "\n".join(lines)


def _parse_slice(text: str | None, n: int) -> list[int]:
    if not text:
        return list(range(n))
    if ":" in text:
        a, _, b = text.partition(":")
        return list(range(int(a or 0), int(b or n)))
    return [int(x) for x in text.split(",")]


def run(indices: list[int], *, out: Path, data_dir: Path, max_samples: int, paths: tuple[str, ...],
        cosim: str, jobs: int, timeout: float, progress: bool = True, write: bool = True) -> dict[str, Any]:
    """Run the records, summarise, and (with `write`) write ``out``.json and .md. Returns the result."""
    data_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows: list[dict] = []
    bar = tqdm(total=len(indices), unit="record", desc="diagnosis generalisation", disable=not progress)
    if jobs <= 1:
        for i in indices:
            rows.append(run_record(i, str(data_dir), max_samples, paths, cosim, timeout))
            bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(run_record, i, str(data_dir), max_samples, paths, cosim, timeout): i
                       for i in indices}
            for fut in as_completed(futures):
                try:
                    rows.append(fut.result())
                except Exception as exc:  # a worker that died: counted, not fatal
                    rows.append({"index": futures[fut], "failures": [{"path": "worker", "error": repr(exc)}]})
                bar.update(1)
    bar.close()
    rows.sort(key=lambda r: r["index"])
    result = {"benchmark": "cosim diagnose default paths on records of an independent simulator",
              "records": len(indices), "slice": f"{indices[0]}..{indices[-1]}" if indices else "",
              "max_samples": max_samples, "cosim": cosim, "jobs": jobs, "wall_s": time.perf_counter() - start,
              "thresholds": THRESHOLDS, "summary": {p: summarize(rows, p) for p in paths},
              "failures": sum(len(r.get("failures", [])) for r in rows), "rows": rows,
              "python": platform.python_version(), "cpus": os.cpu_count()}
    if write:
        _write(result, out)
    return result


def rescore(path: Path, data_dir: Path, out: Path, offset_heldout: tuple[str, ...] = ()) -> dict[str, Any]:
    """An earlier result re-summarised (with the records' annotations made again from `data_dir`) and written to
    ``out``.json and .md. For the paths in `offset_heldout`, the held-out figures of records with an ``offset``
    finding are measured again (:func:`heldout_figures`; the records' model_after files must be that run's)."""
    result = json.loads(path.read_text())
    for row in result["rows"]:
        folder = data_dir / f"record_{row['index']:04d}_{result['max_samples']}"
        if "record" in row and (folder / "truth.json").exists():
            truth = json.loads((folder / "truth.json").read_text())
            row["record"]["nonlinear"] = nonlinear_part(truth["spec"], truth["cli"], folder)
            row["record"]["linear_equivalent"] = linear_equivalent(truth["spec"], row["record"]["nonlinear"])
            for p in offset_heldout:  # measured again against the model without the constant
                res = row.get(p, {})
                named = [e["name"] for e in res.get("effects", [])]
                if "offset" in named and (folder / f"model_after_{p}.json").exists():
                    res.update(heldout_figures(p, named, folder, truth["spec"], truth["cli"]))
    paths = [p for p in ("a", "b") if p in result["summary"]]
    result["summary"] = {p: summarize(result["rows"], p) for p in paths}
    _write(result, out)
    return result


def _write(result: dict[str, Any], out: Path, render=None) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    md = (render or markdown)(result)
    for suffix, text in ((".json", json.dumps(result, indent=1, default=float) + "\n"), (".md", md)):
        tmp = out.with_suffix(suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace(out.with_suffix(suffix))


def add_run_arguments(parser: argparse.ArgumentParser, paths: str) -> None:
    """The options of a run over records (jobs, folders, record length, paths, time-out, the cosim to run)."""
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--out", default=str(RESULTS), help="results folder")
    parser.add_argument("--data", default=None,
                        help="where records are generated and kept (default $TMPDIR/cosim-diagnosis-records)")
    parser.add_argument("--max-samples", type=int, default=ip.DEFAULT_MAX_SAMPLES)
    parser.add_argument("--paths", default=paths)
    parser.add_argument("--timeout", type=float, default=600.0, help="per CLI call, s")
    parser.add_argument("--cosim", default=shutil.which("cosim", path=str(Path(sys.executable).parent)) or "cosim")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=200, help="records 0..n-1")
    parser.add_argument("--slice", default=None, help="a subset: 'A:B' or 'i,j,k'")
    add_run_arguments(parser, paths="a,b")
    parser.add_argument("--offset-heldout", default="", metavar="PATHS",
                        help="with --rescore: measure the held-out figures of offset findings again for these paths "
                             "(e.g. 'a'; the records' model_after files must be from that result's run)")
    parser.add_argument("--rescore", default=None, metavar="JSON",
                        help="re-summarise an earlier result file (its records kept in --data) instead of running")
    args = parser.parse_args()
    indices = _parse_slice(args.slice, args.n)
    data = Path(args.data) if args.data else Path(os.environ.get("TMPDIR", "/tmp")) / "cosim-diagnosis-records"
    if args.rescore:
        again = tuple(p.strip() for p in args.offset_heldout.split(",") if p.strip())
        print(markdown(rescore(Path(args.rescore), data, Path(args.out) / "diagnosis_generalization", again)))
        return
    result = run(indices, out=Path(args.out) / "diagnosis_generalization", data_dir=data,
                 max_samples=args.max_samples, paths=tuple(p.strip() for p in args.paths.split(",")),
                 cosim=args.cosim, jobs=args.jobs, timeout=args.timeout)
    print(markdown(result))


if __name__ == "__main__":
    main()
