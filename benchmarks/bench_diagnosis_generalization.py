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

Records 200 on are the families of ``benchmarks/independent_families.py`` (one-way pairs, saturation and dead
zone, Stribeck with and without slow motion, gravity at large and small swings, Duffing by position only, two
tanks with square-root outflow and overflow, fixed-step Euler records), 5 k-50 k samples. A pair is diagnosed
as one run over its two files (``cosim diagnose train.csv train_b.csv ...``), and each file alone
(``row["alone"]``: does it claim only what it can show?). The diagnosis JSON's ``"ambiguous"`` sets are scored
too, and every record is binned by its effects' visibility as the generator measured it (issue 39's tables,
records 0-199 and 200 on apart; the scoring is in ``benchmarks/_generalization_scoring.py``).

Results go to benchmarks/results/diagnosis_generalization.json and .md.

Run:  python benchmarks/bench_diagnosis_generalization.py [--n 200] [--slice 0:10] [--jobs 2] [--out DIR]
      [--max-samples 30000] [--paths a,b] [--cosim PATH_TO_cosim]    (--slice 200:228: the families)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
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
from _generalization_scoring import (  # noqa: E402, F401  (the scoring's names, as they were here)
    ISSUE_THRESHOLDS,
    THRESHOLDS,
    VISIBILITY_BINS,
    claims,
    estimate,
    input_gain,
    markdown,
    score,
    summarize,
    visibility_of,
)

RESULTS = Path(__file__).resolve().parent / "results"
WORSE_TOLERANCE = 1e-3  # held-out NRMSE after > before * (1 + this): the effect made it worse


# ---------------------------------------------------------------------------------------------- records
def record_folder(data_dir: Path, index: int, max_samples: int | None) -> Path:
    """Where record `index` is kept (`max_samples` None: the generator's own length, 30 k below 200)."""
    size = max_samples if max_samples is not None else (ip.DEFAULT_MAX_SAMPLES if index < 200 else "full")
    return data_dir / f"record_{index:04d}_{size}"


def prepare(index: int, data_dir: Path, max_samples: int | None) -> Path:
    """The folder of record `index`, generated unless already there from this version of the generator
    (truth.json is written last)."""
    import independent_families as fam

    folder = record_folder(data_dir, index, max_samples)
    truth = folder / "truth.json"
    old = json.loads(truth.read_text()) if truth.is_file() else None
    if old is None or old.get("generator") != ip.GENERATOR_VERSION or \
            (index >= fam.FIRST_INDEX and old["spec"].get("families_version") != fam.FAMILIES_VERSION):
        ip.make_record(index, max_samples=max_samples).write(folder)
    return folder


def commands(folder: Path, cli: dict, cosim: str) -> dict[str, list[list[str]]]:
    """The command lines of paths (a) and (b) for a record (all its data files: a pair's two together), and
    ``alone``: a pair's files each diagnosed by itself (path (a)'s command)."""
    files = [str(folder / f) for f in cli.get("data", ["train.csv"])]
    common = ["--state", ",".join(cli["states"]), "--input", cli["input"]]
    derive_diag = ["--derive", ",".join(cli["derive"])] if cli["derive"] else []
    derive_id = ["--derive", ",".join(f"{p}_dot={p}" for p in cli["derive"])] if cli["derive"] else []
    return {
        "a": [[cosim, "diagnose", *files, *common, *derive_diag, "--json", "-o", str(folder / "model_after_a.json")]],
        "b": [[cosim, "identify", *files, *common, *derive_id, "-o", str(folder / "model.json")],
              [cosim, "diagnose", *files, *common, *derive_diag, "--model", str(folder / "model.json"), "--json",
               "-o", str(folder / "model_after_b.json")]],
        "alone": [[cosim, "diagnose", str(folder / f), *common, *derive_diag, "--json", "-o",
                   str(folder / f"model_after_alone_{k}.json")] for k, f in enumerate(cli.get("alone", []))],
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


# ---------------------------------------------------------------------------------------------- held-out error
def heldout_nrmse(model_path_or_model: Any, folder: Path, spec: dict, cli: dict) -> float:
    """Free-run NRMSE % of a model on the held-out twin, against its noise-free states, from its true start (a
    pair's two twins: the mean)."""
    from cosim.identify.model import IdentifiedModel

    model = model_path_or_model if isinstance(model_path_or_model, IdentifiedModel) else \
        IdentifiedModel.load(model_path_or_model)
    files = cli.get("heldout_clean", ["heldout_clean.npz"])
    return float(np.mean([_nrmse_on(model, dict(np.load(folder / f)), spec, cli) for f in files]))


def _nrmse_on(model: Any, clean: dict[str, np.ndarray], spec: dict, cli: dict) -> float:
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


def _train_data(folder: Path, cli: dict, every: bool = False):
    """The train record as ``cosim diagnose`` reads it (derived velocities too); `every`: the list of all the
    record's data files (a pair's two)."""
    from cosim.data.datafile import load_data

    states, derived = cli["states"], cli["derive"]
    derived_names = {f"{p}_dot" for p in derived}
    columns = [s for s in states if s not in derived_names] + [cli["input"]]
    roles = {**dict.fromkeys(states, "state"), cli["input"]: "input"}
    data = [load_data(folder / f, columns=columns, roles=roles, derive=derived).select([*states, cli["input"]])
            for f in cli.get("data", ["train.csv"])]
    return data if every else data[0]


def _model_from(data: dict | None):
    """A model from the dict form a diagnosis JSON holds (None: none given)."""
    from cosim.identify.model import IdentifiedModel

    return IdentifiedModel.from_dict(data) if data else None


def _model_before_a(folder: Path, cli: dict):
    """Path (a)'s model before, fitted in-process as ``cosim diagnose`` fits it without --model."""
    from cosim.diagnose.diagnosis import BASE_SETTINGS  # the settings `cosim diagnose` identifies with
    from cosim.identify.sindyc import SINDYc

    return SINDYc(**BASE_SETTINGS).fit(_train_data(folder, cli, every=True), states=cli["states"],
                                       inputs=[cli["input"]]).model_


def _without_constant(model: Any, folder: Path, cli: dict):
    """`model` refitted on the train record (output error) without the constant of its dynamic rows.

    An ``offset`` finding is the base model's constant kept (``cosim diagnose`` identifies with a constant and
    judges it last, against the model refitted without it): compared with the model before, which has the
    constant too, it would measure refit drift only. This is the model it is judged against. (A pair's: refitted
    on its first record.)
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
        family = "families_version" in spec
        row["record"].update({k: spec.get(k) for k in ("family", "variant", "inner_family", "integrator")})
        row["record"]["nonlinear"] = visibility_of(spec) if family else nonlinear_part(spec, cli, folder)
        row["record"]["linear_equivalent"] = None if family else linear_equivalent(spec, row["record"]["nonlinear"])
        row["record"]["visibility"] = visibility_of(spec, row["record"]["nonlinear"])
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
        res["ambiguous"] = payload.get("ambiguous") or []
        after_path = folder / f"model_after_{path}.json"
        res.update(score(spec, cli, effects, after_path, res["ambiguous"]))
        if effects and heldout:
            try:
                # path (a)'s model before: the base its command identified, as its JSON gives it (identified
                # again here only where the JSON has none: older cosim versions)
                given = _model_from(payload.get("model_before")) if path == "a" else None
                res.update(heldout_figures(path, [e["name"] for e in effects], folder, spec, cli, before=given))
            except Exception as exc:
                row["failures"].append({"path": path, "command": "held-out simulation",
                                        "error": f"{type(exc).__name__}: {exc}"})
    if "a" in paths and cmds.get("alone"):
        row["alone"] = [_alone(argv, k, spec, timeout) for k, argv in enumerate(cmds["alone"])]
    return row


def _alone(argv: list[str], k: int, spec: dict, timeout: float) -> dict[str, Any]:
    """One record of a pair diagnosed by itself: what it claims, and whether it claims only what it can show
    (an effect it shows as another, ``shows_alone_as``, or one visible at least 1x alone)."""
    rc, out, err, secs = _run(argv, timeout)
    res: dict[str, Any] = {"command": " ".join(argv), "seconds": secs, "ok": rc == 0}
    if rc != 0:
        res["error"] = (err.strip().splitlines() or ["(no message)"])[-1]
        return res
    payload = json.loads(out)
    named = [e["name"] for e in payload.get("effects", [])]
    sets = [list(a.get("effects", [])) for a in payload.get("ambiguous") or []]
    shown = {e["shows_alone_as"] for e in spec["effects"] if e.get("shows_alone_as")}
    shown |= {e["name"] for e in spec["effects"] if e.get("visibility_alone", [0.0] * (k + 1))[k] >= 1.0}
    res.update({"named": named, "ambiguous_sets": sets,
                "claims_only_shown": all(n in shown for n in [*named, *(x for s in sets for x in s)]),
                "effects": payload.get("effects", [])})
    return res


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
        folder = record_folder(data_dir, row["index"], result["max_samples"])
        if "record" in row and (folder / "truth.json").exists():
            truth = json.loads((folder / "truth.json").read_text())
            row["record"]["nonlinear"] = visibility_of(truth["spec"])
            if "families_version" not in truth["spec"]:
                row["record"]["nonlinear"] = nonlinear_part(truth["spec"], truth["cli"], folder)
                row["record"]["linear_equivalent"] = linear_equivalent(truth["spec"], row["record"]["nonlinear"])
            row["record"]["visibility"] = visibility_of(truth["spec"], row["record"]["nonlinear"])
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
    parser.add_argument("--max-samples", type=int, default=None,
                        help="shorten records (default: the generator's lengths, 30 k below record 200)")
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
