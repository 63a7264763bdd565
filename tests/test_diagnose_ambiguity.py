"""Readings the data cannot tell apart (``ambiguous``, ``to_separate``) and the experiment that settles them.

A pendulum ``m x'' = u - b x' - G sin x`` swinging less than 0.2 rad is, within its noise, a spring to ground:
the answer is the gravity-or-spring set with the swing that would separate them, not "no effect". A true spring
over a swing where a sine would bend is no set. Plants simulated here by scipy's solve_ivp from their own
equations; the experiment on a plant by the bundled FMU with its gravity unbalance on (``--plant``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

from cosim.cli import main
from cosim.diagnose.ambiguity import INPUT_SCALES

M, B, G = 0.1, 0.4, 0.4
DT, T = 3e-3, 12.0


def _input(seed: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, T + DT / 2, DT)
    edges = np.cumsum(rng.uniform(0.8, 2.0, 20))
    return t, rng.uniform(-1.0, 1.0, 21)[np.searchsorted(edges, t)] * size


def _run(t: np.ndarray, u: np.ndarray, spring: bool) -> np.ndarray:
    def rhs(tt, s):
        k = min(int(tt / DT), len(t) - 1)  # the sampled input, held
        force = G * s[0] if spring else G * np.sin(s[0])
        return [s[1], (u[k] - B * s[1] - force) / M]

    return solve_ivp(rhs, (0.0, t[-1]), [0.0, 0.0], t_eval=t, max_step=DT, rtol=1e-9, atol=1e-12).y


def _csv(path, *, size: float, spring: bool = False, seed: int = 3, noise: float = 0.02) -> str:
    t, u = _input(seed, size)
    x, v = _run(t, u, spring)
    rng = np.random.default_rng(seed + 100)
    x = x + rng.normal(scale=noise * np.ptp(x), size=x.size)
    v = v + rng.normal(scale=noise * np.ptp(v), size=v.size)
    np.savetxt(path, np.column_stack([t, x, v, u]), delimiter=",", header="t,x,v,u", comments="")
    return str(path)


def _diagnose(path: str, *more: str) -> dict:
    result = CliRunner().invoke(main, ["diagnose", path, "--state", "x,v", "--input", "u", "--json", *more])
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_small_swings_of_a_pendulum_are_the_gravity_or_spring_set(tmp_path):
    t, u = _input(3, 0.06)
    swing = float(np.max(np.abs(_run(t, u, spring=False)[0])))
    assert 0.05 < swing < 0.2  # where sin x is x within the noise
    html = tmp_path / "diagnosis.html"
    payload = _diagnose(_csv(tmp_path / "small.csv", size=0.06), "--report", str(html))
    assert payload["effects"] == [], payload["message"]
    sets = payload["ambiguous"]
    assert [s["effects"] for s in sets] == [["gravity", "spring"]], payload["message"]
    assert sets[0]["attached_to"] == "x" and abs(sets[0]["delta_bic"]) <= sets[0]["margin"]
    assert "cannot tell them apart" in payload["message"] and sets[0]["sentence"] in payload["message"]
    plan = sets[0]["to_separate"]
    assert plan["quantity"] == "amplitude" and plan["signal"] == "x" and plan["input_scale"] in INPUT_SCALES
    assert plan["at_least"] > 1.5 * plan["now"]
    assert payload["to_separate"] == [{"effects": ["gravity", "spring"], **plan}]
    assert "Cannot tell apart" in html.read_text(encoding="utf-8")  # the report's page says it too
    # the swing promised is the one the plant itself reaches under that input (the gravity reading's free run)
    reached = float(np.ptp(_run(t, u * plan["input_scale"], spring=False)[0])) / 2
    assert plan["at_least"] == pytest.approx(reached, rel=0.15)


def test_a_spring_over_a_swing_where_a_sine_bends_is_no_set(tmp_path):
    t, u = _input(3, 0.4)
    assert float(np.max(np.abs(_run(t, u, spring=True)[0]))) > 0.6
    payload = _diagnose(_csv(tmp_path / "spring.csv", size=0.4, spring=True))
    assert payload["effects"] == [] and payload["ambiguous"] == [], payload["message"]


def test_plant_options_are_checked_before_any_run(tmp_path):
    data = _csv(tmp_path / "small.csv", size=0.06)
    out = tmp_path / "model.json"
    for more, said in ((["--plant", "bundled"], "has no variable 'x', 'v', 'u' of the data"),
                       (["--set", "mgl=1"], "give --plant FMU too"),
                       (["--plant", str(tmp_path / "none.fmu")], "not found")):
        result = CliRunner().invoke(main, ["diagnose", data, "--state", "x,v", "--input", "u", "-o", str(out),
                                           *more])
        assert result.exit_code == 2, result.output
        assert said in result.output and len(result.output.strip().splitlines()) == 1, result.output
        assert not out.exists()


@pytest.mark.slow
def test_the_experiment_on_the_plant_names_gravity(tmp_path):
    """The bundled servo hanging as a pendulum (mgl 4440 N m, about 0.3 Hz), swinging ±0.05 rad: the record
    leaves gravity or a spring open; `--plant bundled` runs the separating input on the FMU and names gravity
    on the load."""
    data = tmp_path / "swing.csv"
    runner = CliRunner()
    made = runner.invoke(main, ["simulate", "bundled", "--input", "Tm=multisine:amp=150,fmin=0.1,fmax=5",
                                "--duration", "8", "--dt", "1/1000", "--set", "mgl=4440", "--noise", "0.01",
                                "--seed", "1", "-o", str(data)])
    assert made.exit_code == 0, made.output
    states = ["--state", "theta_m,omega_m,theta_L,omega_L", "--input", "Tm", "--json"]
    result = runner.invoke(main, ["diagnose", str(data), *states, "--plant", "bundled", "--set", "mgl=4440"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.stdout)
    assert [(e["name"], e["attached_to"]) for e in payload["effects"]] == [("gravity", "theta_L")], \
        payload["message"]
    assert payload["ambiguous"] == [] and payload["experiments"], payload["message"]
    # an experiment runs only for a set the record alone left open: this one was for gravity or a spring (the
    # record diagnosed alone, without --plant, gives that set; not run again here: 16 s)
    assert payload["experiments"][0]["effects"] == ["gravity", "spring"]
    assert payload["experiments"][0]["swing"] > 0.3  # it swung where the sine bends


def _family_plant(index: int, max_samples: int = 4000):
    """Record `index` of the benchmark's families (benchmarks/independent_families.py: its own equations and
    scipy, nothing of cosim) as the generator draws it: its system, its first part's input, sample time and
    noise fraction."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # benchmarks/ is not a package
    import independent_families as fam

    which = fam.family_of(index)
    rng = np.random.default_rng([index, 0])
    dt, n = fam._sizes(rng, max_samples)
    noise_frac = fam._loguniform(rng, 0.002, 0.05)
    draft = fam.BUILDERS[which["inner"]](rng, dt, n, which["variant"], {"method": "lsoda"}, index)
    return draft["system"], draft["parts"][0], dt, noise_frac


@pytest.mark.slow
def test_a_rival_set_names_the_swing_that_separates_it_and_that_swing_does(tmp_path):
    """Record 204 of the families, a hardening spring (Duffing, k3 1.375) measured by position only, swinging
    +-0.61: over that swing sin x bends as x**3 does, and the answer is the cubic-or-gravity set. The set names
    the swing that would separate them; the plant (the generator's own equations) run under that input and
    diagnosed beside the record names the cubic spring alone."""
    system, part, dt, noise_frac = _family_plant(204)
    import _family_system as fs  # (benchmarks/, on the path now)
    t = np.arange(len(part["u"]) + 1) * dt
    k = system.states.index("x")

    def written(u: np.ndarray, seed: int, sigma: float | None = None) -> tuple[str, float, float]:
        states = fs.simulate(system, u, dt, part["x0"])
        sigma = noise_frac * float(np.ptp(states[:, k])) if sigma is None else sigma
        x = states[:, k] + sigma * np.random.default_rng(seed).standard_normal(len(t))
        path = tmp_path / f"run{seed}.csv"
        np.savetxt(path, np.column_stack([t, x, np.append(u, u[-1])]), delimiter=",", header="time,x,u",
                   comments="")
        return str(path), float(np.ptp(states[:, k])) / 2, sigma

    options = ["--state", "x,x_dot", "--derive", "x", "--input", "u", "--json"]
    record, swing, sigma = written(part["u"], 1)
    result = CliRunner().invoke(main, ["diagnose", record, *options], catch_exceptions=False)
    payload = json.loads(result.stdout)
    assert [(e["name"], e["attached_to"]) for e in payload["effects"]] == [("cubic_stiffness", "x")], \
        payload["message"]
    (found,) = payload["ambiguous"]
    plan = found["to_separate"]
    assert found["effects"] == ["cubic_stiffness", "gravity"] and plan["signal"] == "x"
    assert plan["input_scale"] in INPUT_SCALES and plan["now"] == pytest.approx(swing, rel=0.05)
    assert plan["at_least"] > plan["now"] and f"±{plan['at_least']:.3g} on x" in found["sentence"]
    # the experiment, on the plant: the swing it predicted, and then no set
    run, reached, _ = written(plan["input_scale"] * part["u"], 2, sigma)
    assert reached == pytest.approx(plan["at_least"], rel=0.05)
    result = CliRunner().invoke(main, ["diagnose", record, run, *options], catch_exceptions=False)
    both = json.loads(result.stdout)
    assert [(e["name"], e["attached_to"]) for e in both["effects"]] == [("cubic_stiffness", "x")], both["message"]
    assert both["ambiguous"] == [] and both["effects"][0]["parameters"]["k3"] == pytest.approx(1.375, rel=0.02)
