"""How much of the generalisation benchmark's gap is the base model, and how much the search? The diagnosis from
the plant's own linear part, and told which effect to look for.

The records and scoring of ``bench_diagnosis_generalization.py``, and two more paths:

(o) ``cosim diagnose DATA.csv --state S --input U [--derive POS] --model model_oracle.json --json -o ..``

where ``model_oracle.json`` is the simulator's own linear plant (``benchmarks/independent_plants.py``: its masses,
shaft, dampers and spring, no effect) as a cosim model: the base no identification can beat, which no user has.
Where the default diagnosis names the right effect no more often from it than from its own identified base, what
limits the benchmark is not the identification but what the records show (an effect's non-linear part beside
the noise) and the diagnosis' acceptance rules. Its held-out figures take the oracle model as the model before.

(e) ``cosim diagnose DATA.csv --state S --input U [--derive POS] --effects ITEMS --json -o ..``

(oe) both: the oracle base and told the true effects, the most any search from this diagnosis could name.

the default path told the record's true effects, each at its true nuisance value (``cogging:periods=17``,
``delay:delay=12``...; records without an effect run the whole catalogue, as path (a)). What it still misses no
search could find: the record does not show the effect against the identified base beyond the acceptance rules
(significance, held-out error). A value the record cannot show is refused (exit 2) and counted as a failure.

Results go to benchmarks/results/diagnosis_oracle.json and .md (with path (a) run beside it for comparison), or
with ``--paths e,a --name diagnosis_told`` to diagnosis_told.json and .md.

Run:  python benchmarks/bench_diagnosis_oracle.py [--slice 0:200] [--jobs 2] [--data DIR] [--paths o,a,e] [--name N]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_diagnosis_generalization as gen  # noqa: E402
import independent_plants as ip  # noqa: E402

ORACLE = "model_oracle.json"


def linear_plant(spec: dict, cli: dict):
    """The simulator's linear plant (no effect) as a cosim model: kinematic rows ``p' = v``, the velocity rows from
    the masses, the shaft and the dampers (`cli` names the states as the record's CLI does)."""
    from cosim.identify.model import IdentifiedModel

    p, states, u = spec["plant"], list(cli["states"]), cli["input"]
    if p["kind"] == "single":
        x, v = states
        rows = {x: {v: 1.0}, v: {x: -p["k"] / p["m"], v: -p["b"] / p["m"], u: 1.0 / p["m"]}}
    else:
        tm, wm, tl, wl = states
        jm, jl, k, c = p["Jm"], p["JL"], p["k"], p["c"]
        rows = {tm: {wm: 1.0}, tl: {wl: 1.0},
                wm: {tm: -k / jm, tl: k / jm, wm: -(c + p["bm"]) / jm, wl: c / jm, u: 1.0 / jm},
                wl: {tm: k / jl, tl: -k / jl, wl: -(c + p["bL"]) / jl, wm: c / jl}}
    terms = (*states, u)
    return IdentifiedModel(states=tuple(states), inputs=(u,), terms=terms,
                           coef=np.array([[rows[s].get(t, 0.0) for t in terms] for s in states]), dt=spec["dt"])


def _write_oracle(folder: Path) -> Path:
    truth = json.loads((folder / "truth.json").read_text())
    return linear_plant(truth["spec"], truth["cli"]).save(folder / ORACLE)


def told_effects(spec: dict) -> str:
    """The ``--effects`` selection of a record's true effects, nuisances at their true values (``"all"`` without
    an effect). The simulator names a nuisance as cosim does, but for the delay (seconds; cosim's in samples)."""
    from cosim.diagnose.effects import EFFECTS

    items = []
    for e in spec["effects"]:
        name, params, nuisance = e["name"], e["params"], EFFECTS[e["name"]].nuisance
        value = round(params["delay_s"] / spec["dt"]) if name == "delay" else params.get(nuisance)
        items.append(f"{name}:{nuisance}={value:.10g}" if value is not None else name)
    return ",".join(items) or "all"


def commands(folder: Path, cli: dict, cosim: str) -> dict[str, list[list[str]]]:
    """The generalisation benchmark's command lines, and those of paths (o) (its model file written here) and
    (e)."""
    cmds = _commands(folder, cli, cosim)
    oracle = _write_oracle(folder)
    diagnose = list(cmds["b"][-1])
    diagnose[diagnose.index("--model") + 1] = str(oracle)
    diagnose[diagnose.index("-o") + 1] = str(folder / "model_after_o.json")
    told = list(cmds["a"][-1])
    told[told.index("-o") + 1] = str(folder / "model_after_e.json")
    spec = json.loads((folder / "truth.json").read_text())["spec"]
    both = list(diagnose)
    both[both.index("-o") + 1] = str(folder / "model_after_oe.json")
    return {**cmds, "o": [diagnose], "e": [[*told, "--effects", told_effects(spec)]],
            "oe": [[*both, "--effects", told_effects(spec)]]}


def heldout_figures(path: str, named: list[str], folder: Path, spec: dict, cli: dict,
                    before: Any = None) -> dict[str, Any]:
    """The benchmark's held-out figures; path (o)'s against the oracle model as the model before, the others'
    against `before` (path (a)'s base as its JSON gives it) as the benchmark's own."""
    return _heldout_figures(path, named, folder, spec, cli, folder / ORACLE if path in ("o", "oe") else before)


_commands, _heldout_figures = gen.commands, gen.heldout_figures


def markdown(result: dict[str, Any]) -> str:
    """The per-effect table of each path, and the records only one of (o) and (a) names right first."""
    titles = {"o": "(o) the plant's own linear part given as `--model`",
              "oe": "(oe) the plant's own linear part, told the true effects",
              "a": "(a) the default path (identifies first)",
              "e": "(e) the default path told the true effects and their nuisance values (`--effects`)"}
    title = "from the plant's own linear part (an oracle base)" if "o" in result["summary"] else \
        "told the records' true effects"
    lines = [f"# Diagnosis {title}", "",
             f"Records {result['slice']} of the generalisation benchmark (at most {result['max_samples']} samples, "
             f"generator version {ip.GENERATOR_VERSION}); {result['jobs']} jobs; {result['wall_s']:.0f} s.", ""]
    for path in result["summary"]:
        s = result["summary"][path]
        lines += [f"## {titles.get(path, path)}", "",
                  "| effect | records | named right first % | false claims % | accepted, worse held-out |",
                  "| --- | --- | --- | --- | --- |"]
        for name, f in [*s["per_effect"].items(), ("**overall**", s["overall"])]:
            lines.append(f"| {name} | {f['records']} | {f['right_first_pct']:.1f} | {f['false_claims_pct']:.1f} "
                         f"| {f['accepted_worse_heldout']} |")
        lines.append("")
    if {"o", "a"} <= set(result["summary"]):
        rows = result["rows"]
        only = {p: [r["index"] for r in rows if r.get(p, {}).get("right_first")
                    and not r.get("a" if p == "o" else "o", {}).get("right_first")] for p in ("o", "a")}
        either = sum(bool(r.get("o", {}).get("right_first") or r.get("a", {}).get("right_first")) for r in rows)
        lines += [f"Named right first from the oracle base only: {', '.join(map(str, only['o'])) or 'none'}; "
                  f"from the identified base only: {', '.join(map(str, only['a'])) or 'none'}. By either: "
                  f"{either} of {len(rows)} ({100.0 * either / max(len(rows), 1):.1f} %).", ""]
    if {"e", "a"} <= set(result["summary"]):
        rows = [r for r in result["rows"] if r.get("truth")]
        found = [r["index"] for r in rows if r.get("e", {}).get("right_first") and not r["a"].get("right_first")]
        missed = [r["index"] for r in rows if not r.get("e", {}).get("right_first")]
        refused = [r["index"] for r in rows if any(f.get("path") == "e" for f in r.get("failures", []))]
        lines += [f"Of {len(rows)} records with an effect, named right first when told and not by the default "
                  f"search: {_listed(found)} ({len(found)}). Not named right first even when told: {len(missed)} "
                  f"({_listed(missed)}); of these the told value was refused as outside what the record shows, or "
                  f"the run failed: {_listed(refused)}.", ""]
        neither = [r["index"] for r in rows if not r.get("e", {}).get("right_first") and not r["a"].get("right_first")]
        either = sum(bool(r.get("e", {}).get("right_first") or r["a"].get("right_first")) for r in result["rows"])
        lines += [f"Named right first by either path: {either} of {len(result['rows'])} "
                  f"({100.0 * either / max(len(result['rows']), 1):.1f} %); by neither, among the records with an "
                  f"effect: {len(neither)} ({_listed(neither)}).", ""]
    return "\n".join(lines)


def _listed(indices: list[int]) -> str:
    return ", ".join(map(str, indices)) or "none"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slice", default="0:200", help="'A:B' or 'i,j,k'")
    gen.add_run_arguments(parser, paths="o,a")
    parser.add_argument("--name", default="diagnosis_oracle",
                        help="the results' file name in --out (diagnosis_told for paths e,a)")
    args = parser.parse_args()
    gen.commands, gen.heldout_figures = commands, heldout_figures  # (the workers are forked: they see these too)
    data = Path(args.data) if args.data else Path(os.environ.get("TMPDIR", "/tmp")) / "cosim-diagnosis-records"
    result = gen.run(gen._parse_slice(args.slice, 200), out=Path(args.out) / args.name, data_dir=data,
                     max_samples=args.max_samples, paths=tuple(p.strip() for p in args.paths.split(",")),
                     cosim=args.cosim, jobs=args.jobs, timeout=args.timeout, write=False)
    gen._write(result, Path(args.out) / args.name, markdown)
    print(markdown(result))


if __name__ == "__main__":
    main()
