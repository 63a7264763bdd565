"""Scoring of ``bench_diagnosis_generalization.py``: what cosim named against the truth, tables and verdicts.

Per record and path (see the benchmark's notes): the right effect named first, or else an ambiguity set of at
most two effects (the diagnosis JSON's ``"ambiguous"``: ``[{"effects": [...], "attached_to", "to_separate"}]``)
that holds it, counted apart; a false claim (an effect named that the record lacks, outside an ambiguity set
holding a true effect, or a set none of whose effects the record has; an effect the record shows as another,
``shows_as``, e.g. a one-way Coulomb friction as an offset, may be named so); parameter errors.

Tables per effect and per visibility bin (:data:`VISIBILITY_BINS`: the effect's non-linear part over the noise,
measured by the generator: ``spec["effects"][i]["visibility"]`` for records 200 on, and for records 0-199
:func:`visibility_0_199`), for records 0-199 and, apart, records 200 on, against the issue's thresholds
(:data:`ISSUE_THRESHOLDS`). The older overall table keeps issue 13's (:data:`THRESHOLDS`).
"""

from __future__ import annotations

import math
import statistics
from pathlib import Path
from typing import Any

import independent_plants as ip
import numpy as np

#: Issue 13's thresholds (the overall table).
THRESHOLDS = {"right_first_pct": (">=", 90.0), "false_claims_pct": ("<=", 5.0),
              "median_param_error_pct": ("<=", 10.0), "accepted_worse_heldout": ("<=", 0),
              "median_time_s": ("<=", 10.0)}
#: Issue 39's, per group of records (0-199; 200 on).
ISSUE_THRESHOLDS = {"right_first_or_set_pct_2x": (">=", 95.0), "ambiguous_pct_2x": ("<=", 10.0),
                    "false_claims_pct": ("<=", 2.0), "wrong_claims_below_1x": ("<=", 0),
                    "accepted_worse_heldout": ("<=", 2), "median_param_error_pct": ("<=", 5.0),
                    "median_time_s_20k": ("<=", 5.0), "p90_time_s_20k": ("<=", 15.0)}
ISSUE_LABELS = {"right_first_or_set_pct_2x": "right first or in a set of <= 2, records >= 2x %",
                "ambiguous_pct_2x": "ambiguity sets, records >= 2x %", "false_claims_pct": "false claims, all %",
                "wrong_claims_below_1x": "wrong claims, records < 1x",
                "accepted_worse_heldout": "accepted effects raising the twin's error (records)",
                "median_param_error_pct": "median parameter error %",
                "median_time_s_20k": "median time s (<= 20 k samples)",
                "p90_time_s_20k": "90th percentile time s (<= 20 k samples)"}
#: Visibility bins (the effect's non-linear part over the noise): >= 2x, 1-2x, < 1x.
VISIBILITY_BINS = ((">= 2x", 2.0, math.inf), ("1-2x", 1.0, 2.0), ("< 1x", -math.inf, 1.0))
#: Effects rated by their plain contribution in records 0-199 (a model's constant, a delay: linear dynamics).
PLAIN = ("offset", "delay")


def visibility_0_199(spec: dict, nonlinear: dict[str, float]) -> dict[str, float]:
    """Per effect of a record 0-199, its visibility: its contribution over the noise (the calibration's ratio,
    alone on the plant) times the share of its force no linear model takes up (:func:`ip.nonlinear_share` on
    the record's noise-free run, given as `nonlinear`, already the product); offsets and delays, which cosim
    names from a linear model's constant or delay, by their contribution alone."""
    return {e["name"]: (float(e["ratio"]) if e["name"] in PLAIN else float(nonlinear.get(e["name"], 0.0)))
            for e in spec["effects"]}


def visibility_of(spec: dict, nonlinear: dict[str, float] | None = None) -> dict[str, float]:
    """Per true effect (its name; the largest of two alike), the visibility the generator measured."""
    if "families_version" not in spec:
        return visibility_0_199(spec, nonlinear or {})
    out: dict[str, float] = {}
    for e in spec["effects"]:
        out[e["name"]] = max(out.get(e["name"], 0.0), float(e["visibility"]))
    return out


def bin_of(value: float) -> str:
    return next(label for label, lo, hi in VISIBILITY_BINS if lo <= value < hi)


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
    if name in ("sqrt_outflow", "hard_stop"):
        key = "a" if name == "sqrt_outflow" else "bound"
        return float(p.get(key, _pick(p, f"{key}_", row)))
    if name == "cubic_stiffness":
        if "k3" in p:
            return float(p["k3"])
        rows = [k[len("coef_"):] for k in p if k.startswith("coef_")]
        motor = ip.cosim_name(cli, "omega_m")
        r = motor if motor in rows else (rows[0] if rows else None)
        if r is None or model_after is None or not model_after.is_file():
            return math.nan
        gain = input_gain(model_after, r, cli["input"])
        sign = -1.0 if r == motor else 1.0  # k3 tw^3 leaves the motor's row and enters the load's
        return sign * float(p[f"coef_{r}"]) / gain if gain else math.nan
    return math.nan


def claims(spec: dict, effects: list[dict], ambiguous: list[dict] | None) -> dict[str, Any]:
    """Right first, right in an ambiguity set (<= 2 effects holding a true one), and the wrong claims."""
    truth = spec["effects"]
    names = {e["name"] for e in truth}
    allowed = names | {e["shows_as"] for e in truth if e.get("shows_as")}
    named = [e["name"] for e in effects]
    sets = [list(a.get("effects", [])) for a in (ambiguous or [])]
    # a set's "spring" is the linear model's spring to ground and constant: the truth of a record without effects
    # and of a plant with a spring to ground (a single mass's k; a two-mass plant's k couples the two)
    plant = spec.get("plant") or {}
    grounded = plant.get("kind") in ("single", "mass") and float(plant.get("k", 0.0)) > 0.0
    held = names | ({"spring"} if not truth or grounded else set())
    holding = [s for s in sets if len(s) <= 2 and held & set(s)]
    covered = {n for s in holding for n in s}
    out: dict[str, Any] = {"named": named, "ambiguous_sets": sets, "ambiguous": bool(sets)}
    if not truth:
        out["right_first"] = not named and not sets
    else:
        out["right_first"] = bool(named) and named[0] in allowed
    out["right_ambiguous"] = bool(not out["right_first"] and holding
                                  and (not named or named[0] in covered | allowed))
    wrong = [n for n in named if n not in allowed and n not in covered]
    wrong += [n for s in sets if not held & set(s) for n in s if n not in allowed]
    out["wrong_claims"] = wrong
    out["false_claim"] = bool(wrong)
    return out


def score(spec: dict, cli: dict, effects: list[dict], model_after: Path | None,
          ambiguous: list[dict] | None = None) -> dict[str, Any]:
    """Right first (or in an ambiguity set), false claim, right place, parameter errors for one path's named
    effects and ambiguity sets."""
    truth = spec["effects"]
    named = [e["name"] for e in effects]
    out: dict[str, Any] = {"attached": [e.get("attached_to") for e in effects], **claims(spec, effects, ambiguous)}
    places = {e["name"]: ip.cosim_name(cli, e["at"]) for e in truth}
    out["right_place"] = bool(named) and named[0] in places and effects[0].get("attached_to") == places[named[0]] \
        if truth else not named
    errors = {}
    for t in truth:
        match = next((e for e in effects if e["name"] == t["name"]
                      and e.get("attached_to") in (None, ip.cosim_name(cli, t["at"]))), None) \
            or next((e for e in effects if e["name"] == t["name"]), None)
        if match is None:
            continue
        try:
            est = estimate(t, match, cli, spec["dt"], model_after)
        except Exception as exc:  # a mapping failure is reported, not fatal
            out.setdefault("notes", []).append(f"parameter of {t['name']}: {exc!r}")
            est = math.nan
        true = float(t["main_value"])
        errors[t["name"] if t["name"] not in errors else f"{t['name']}@{t['at']}"] = {"true": true, "estimate": est,
                             "rel_error_pct": abs(est - true) / abs(true) * 100 if math.isfinite(est) else math.inf}
    out["param_errors"] = errors
    return out




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
    groups = {label: issue_figures(group, path) for label, group in
              (("records 0-199", [r for r in rows if r["index"] < 200]),
               ("records 200 on", [r for r in rows if r["index"] >= 200])) if group}
    return {"per_effect": per_effect, "overall": overall, "groups": groups}


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
             f"Records {result['slice']}, at most {result['max_samples'] or 'the generator-drawn'} samples each; "
             f"cosim: `{result['cosim']}`; "
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
        lines += ["", "| overall | measured | issue 13's threshold | met |", "| --- | --- | --- | --- |"]
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
        for label, g in s.get("groups", {}).items():
            lines += issue_markdown(label, g)
        lines.append("")
    pairs = [r for r in result["rows"] if r.get("alone")]
    if pairs:
        lines += ["## One-way pairs, each record alone (path (a)'s command on one file)", ""]
        lines += [f"- record {r['index']}, file {k}: named {x.get('named', x.get('error'))}, sets "
                  f"{x.get('ambiguous_sets', [])}; claims only what it can show: {x.get('claims_only_shown')}"
                  for r in pairs for k, x in enumerate(r["alone"])] + [""]
    fails = [(r["index"], f) for r in result["rows"] for f in r.get("failures", [])]
    lines += [f"## Failures ({len(fails)})", ""]
    lines += [f"- record {i} ({f['path']}): `{f.get('command', '')}` -> exit {f.get('exit', '-')}: {f['error']}"
              for i, f in fails] or ["none"]
    lines += ["", "Two-effect records count in both effects' rows. A record without an effect is 'named right' "
              "when nothing is named. Held-out: free run from the twin's true initial state, NRMSE % against its "
              "noise-free states; 'worse' when after > before x 1.001.", ""]
    return "\n".join(lines)


def _largest(row: dict) -> float:
    vis = row.get("record", {}).get("visibility") or {}
    return max(vis.values(), default=0.0)


def issue_figures(rows: list[dict], path: str) -> dict[str, Any]:
    """Issue 39's table for one group of records: per visibility bin (the record's largest effect), per effect
    and bin (the effect's own), and the thresholds (:data:`ISSUE_THRESHOLDS`)."""
    def figures(group: list[dict], effect: str | None = None) -> dict[str, Any]:
        res = [r.get(path, {}) for r in group]
        errors = [e["rel_error_pct"] for x in res for name, e in x.get("param_errors", {}).items()
                  if effect is None or name.split("@")[0] == effect]
        out = {"records": len(group), "failed": sum(not x.get("ok") for x in res),
               "right_first_pct": _pct([bool(x.get("right_first")) for x in res]),
               "in_set_pct": _pct([bool(x.get("right_ambiguous")) for x in res]),
               "ambiguous_pct": _pct([bool(x.get("ambiguous")) for x in res]),
               "false_claims_pct": _pct([bool(x.get("false_claim")) for x in res]),
               "wrong_claims": sum(bool(x.get("false_claim")) for x in res),
               "median_param_error_pct": _median(errors), "param_errors": len(errors),
               "accepted_worse_heldout": sum(bool(x.get("heldout_worse")) for x in res)}
        if effect is not None:
            out["found_pct"] = _pct([effect in x.get("named", [])
                                     or any(effect in s for s in x.get("ambiguous_sets", [])) for x in res])
        return out

    by_bin = {label: figures([r for r in rows if r.get("truth") and bin_of(_largest(r)) == label])
              for label, _, _ in VISIBILITY_BINS}
    by_bin["no effect"] = figures([r for r in rows if "truth" in r and not r["truth"]])
    per_effect: dict[str, dict[str, Any]] = {}
    for r in rows:
        for name, v in (r.get("record", {}).get("visibility") or {}).items():
            per_effect.setdefault(name, {}).setdefault(bin_of(v), []).append(r)
    per_effect_bin = {name: {b: figures(group, name) for b, group in sorted(bins.items())}
                      for name, bins in sorted(per_effect.items())}
    strong = [r for r in rows if r.get("truth") and _largest(r) >= 2.0]
    weak = [r for r in rows if _largest(r) < 1.0]
    res_all = [r.get(path, {}) for r in rows]
    short = [x["seconds"] for r, x in zip(rows, res_all, strict=True)
             if x.get("ok") and r.get("record", {}).get("samples", math.inf) <= 20_001]
    overall = figures(rows)
    values = {"right_first_or_set_pct_2x": _pct([bool(r.get(path, {}).get("right_first")
                                                      or r.get(path, {}).get("right_ambiguous")) for r in strong]),
              "ambiguous_pct_2x": _pct([bool(r.get(path, {}).get("ambiguous")) for r in strong]),
              "false_claims_pct": overall["false_claims_pct"],
              "wrong_claims_below_1x": sum(bool(r.get(path, {}).get("false_claim")) for r in weak),
              "accepted_worse_heldout": overall["accepted_worse_heldout"],
              "median_param_error_pct": overall["median_param_error_pct"],
              "median_time_s_20k": _median(short),
              "p90_time_s_20k": float(np.percentile(short, 90)) if short else math.nan}
    return {"by_bin": by_bin, "per_effect_bin": per_effect_bin, "values": values,
            "pass": {k: _meets(values[k], *ISSUE_THRESHOLDS[k]) for k in ISSUE_THRESHOLDS},
            "records": len(rows), "records_2x": len(strong), "records_below_1x": len(weak)}


def issue_markdown(label: str, g: dict[str, Any]) -> list[str]:
    """Issue 39's tables of one group of records, as markdown lines."""
    head = ("| {} | records | failed | right first % | in a set % | any set % | false claims % | median parameter "
            "error % (n) | worse twin |")
    lines = ["", f"### Issue 39, {label}: by visibility (the effect's non-linear part over the noise, measured by the "
             "generator)", "", head.format("visibility (largest effect)"), "| --- " * 9 + "|"]

    def row(name: str, f: dict) -> str:
        return (f"| {name} | {f['records']} | {f['failed']} | {f['right_first_pct']:.0f} | {f['in_set_pct']:.0f} | "
                f"{f['ambiguous_pct']:.0f} | {f['false_claims_pct']:.0f} | {f['median_param_error_pct']:.1f} "
                f"({f['param_errors']}) | {f['accepted_worse_heldout']} |")
    lines += [row(b, f) for b, f in g["by_bin"].items()]
    lines += ["", head.format("effect, its visibility") + " found % |", "| --- " * 10 + "|"]
    for name, bins in g["per_effect_bin"].items():
        lines += [row(f"{name}, {b}", f) + f" {f['found_pct']:.0f} |" for b, f in bins.items()]
    lines += ["", f"| issue 39 ({g['records']} records, {g['records_2x']} >= 2x, {g['records_below_1x']} < 1x) "
              "| measured | threshold | met |", "| --- | --- | --- | --- |"]
    lines += [f"| {ISSUE_LABELS[k]} | {g['values'][k]:.3g} | {op} {limit:g} | {'yes' if g['pass'][k] else 'NO'} |"
              for k, (op, limit) in ISSUE_THRESHOLDS.items()]
    return lines
