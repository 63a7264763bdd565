"""The benchmark's independent simulator (benchmarks/independent_plants.py) against known answers.

A single mass with viscous friction under a constant force matches the analytic solution; a record's effect,
re-simulated here with and without it on the record's own input, contributes 2-20x the noise, as its
calibration says; the written noise has the stated level; a record is the same from the same seed.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))  # benchmarks/ is not a package
import independent_plants as ip  # noqa: E402
from _held_lsoda import lsoda_interval  # noqa: E402


def test_single_mass_matches_the_analytic_solution():
    m, b, force, dt, n = 2.0, 0.5, 3.0, 1e-2, 400
    plant = ip.Plant("single", {"m": m, "b": b, "k": 0.0})
    states, cmd = ip.simulate(plant, [], dt, n, u=np.full(n, force))
    t = np.arange(n + 1) * dt
    v = force / b * (1 - np.exp(-b * t / m))
    x = force / b * (t - m / b * (1 - np.exp(-b * t / m)))
    assert np.allclose(cmd, force)
    assert np.allclose(states[:, 1], v, rtol=1e-5, atol=1e-8)
    assert np.allclose(states[:, 0], x, rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("effects", [[], [{"name": "coulomb_friction", "row": "omega_m",
                                           "params": {"Fc": 2.0, "eps": 1e-4}},
                                          {"name": "backlash", "params": {"half_width": 1e-3}}]])
def test_an_interval_by_the_reused_lsoda_is_solve_ivps_to_the_last_bit(effects):
    """The simulators integrate every sample interval by :func:`_held_lsoda.lsoda_interval`, a reused LSODA:
    the records must be those solve_ivp gave (records 0-199 are kept as they were)."""
    from scipy.integrate import solve_ivp

    plant = ip.Plant("two_mass", {"Jm": 0.01, "JL": 0.05, "k": 80.0, "c": 0.02, "bm": 0.01, "bL": 0.05})
    f = ip._rhs(plant, effects)
    rng = np.random.default_rng(7)
    y = y_ref = np.zeros(4)
    for k in range(150):
        u, a, b = float(rng.normal(0, 5)), k * 1e-3, (k + 1) * 1e-3
        b = a + 0.37e-3 if k % 50 == 49 else b  # a delay's split interval
        y = lsoda_interval(lambda t, s, u=u: f(t, s, u), a, b, y, rtol=1e-7, atol=1e-10, max_step=b - a,
                           min_step=1e-9 * (b - a))
        y_ref = solve_ivp(f, (a, b), y_ref, method="LSODA", args=(u,), rtol=1e-7, atol=1e-10, max_step=b - a,
                          min_step=1e-9 * (b - a)).y[:, -1]
        assert np.array_equal(y, y_ref), k
    assert np.max(np.abs(y)) > 1e-3  # it moved


def test_coulomb_friction_sticks_below_its_force():
    """A force below Fc leaves the mass (nearly) at rest: the sharp tanh is integrated, not smeared."""
    plant = ip.Plant("single", {"m": 1.0, "b": 0.1, "k": 0.0})
    friction = {"name": "coulomb_friction", "row": "v", "params": {"Fc": 1.0, "eps": 1e-5}}
    states, _ = ip.simulate(plant, [friction], 1e-3, 1000, u=np.full(1000, 0.8))
    # stuck: the speed sits where the smooth friction balances the force, eps * atanh(0.8), 1e-5 m/s
    assert states[-1, 1] == pytest.approx(1e-5 * math.atanh(0.8), rel=1e-3)
    assert np.max(np.abs(states[:, 1])) < 2e-5
    moving, _ = ip.simulate(plant, [friction], 1e-3, 1000, u=np.full(1000, 1.5))
    assert moving[-1, 1] == pytest.approx(0.5 * 1.0 * (1 - math.exp(-0.1)) / 0.1, rel=1e-3)  # (u-Fc)/b (1-e^-bt/m)


@pytest.fixture(scope="module")
def record():
    """An open-loop record with one effect (found among the first seeds), short."""
    for i in range(40):
        rec = ip.make_record(i, max_samples=1500)
        if rec.spec["excitation"] != "closed_loop" and len(rec.spec["effects"]) == 1:
            return rec
    raise AssertionError("no open-loop record with one effect among the first 40 seeds")


def test_calibrated_effect_contributes_2_to_20_times_the_noise(record):
    spec = record.spec
    plant = ip.Plant(spec["plant"]["kind"], {k: v for k, v in spec["plant"].items() if k != "kind"})
    n = spec["samples"] - 1
    u = record.train[plant.input][:-1]
    effects = [{k: e[k] for k in ("name", "at", "row", "params")} for e in spec["effects"]]
    without, _ = ip.simulate(plant, [], spec["dt"], n, u=u)
    with_it, _ = ip.simulate(plant, effects, spec["dt"], n, u=u)
    written = [s for s in plant.states if s in record.train]
    ratios = [np.sqrt(np.mean((with_it[:, plant.states.index(s)] - without[:, plant.states.index(s)]) ** 2))
              / spec["sigma"][s] for s in written]
    ratio = float(np.sqrt(np.mean(np.square(ratios))))
    assert 2.0 <= ratio <= 20.0
    assert ratio == pytest.approx(spec["effects"][0]["ratio"], rel=1e-6)
    for s in written:  # the written noise is the stated level
        noise = record.train[s] - with_it[:, plant.states.index(s)]
        assert np.std(noise) == pytest.approx(spec["sigma"][s], rel=0.1)


def test_a_record_is_the_same_from_the_same_seed(record):
    again = ip.make_record(record.index, max_samples=1500)
    for name, values in record.train.items():
        assert np.array_equal(values, again.train[name])
    for name, values in record.heldout.items():
        assert np.array_equal(values, again.heldout[name])
    twin_input, train_input = record.heldout[ip.Plant(record.spec["plant"]["kind"], {}).input], \
        record.train[ip.Plant(record.spec["plant"]["kind"], {}).input]
    assert not np.array_equal(twin_input, train_input)  # the twin has its own excitation


def test_replay_reproduces_the_noise_free_run(record):
    spec = record.spec
    clean = ip.replay(spec, record.heldout_clean[ip.Plant(spec["plant"]["kind"], {}).input])
    for name, values in clean.items():
        assert np.array_equal(values, record.heldout_clean[name]), name


@pytest.mark.parametrize(("effect", "share"), [
    # a saturation under a two-level command (+-2, level 1): a gain change, all of it linear
    ({"name": "saturation", "params": {"level": 1.0}}, 0.0),
    # gravity over +-0.1 rad: sin x is x to 0.2 %; over +-2 rad it is far from linear
    ({"name": "gravity", "row": "v", "params": {"G": 1.0}}, None),
])
def test_nonlinear_share_of_an_effects_force(effect, share):
    t = np.linspace(0.0, 1.0, 2001)
    u = 2.0 * np.sign(np.sin(2 * np.pi * 3 * t))
    spec = {"plant": {"kind": "single", "m": 1.0, "b": 1.0, "k": 1.0}, "effects": [effect]}
    if share is not None:
        clean = {"x": np.sin(t), "v": np.cos(t), "u": u}
        assert ip.nonlinear_share(spec, clean)[effect["name"]] == pytest.approx(share, abs=1e-12)
        return
    small = ip.nonlinear_share(spec, {"x": 0.1 * np.sin(2 * np.pi * t), "v": np.cos(t), "u": u})["gravity"]
    large = ip.nonlinear_share(spec, {"x": 2.0 * np.sin(2 * np.pi * t), "v": np.cos(t), "u": u})["gravity"]
    assert small < 0.002 < 0.05 < large


def test_an_effect_a_linear_model_takes_up_whole_is_drawn_again():
    # a dead zone of 0.5 under a command of +-2 only: the plant sees +-1.5, a gain; a wider-ranging command
    # shows it
    plant = ip.Plant("single", {"m": 1.0, "b": 1.0, "k": 0.0})
    dt, n = 1e-2, 400
    two_level = 2.0 * np.sign(np.sin(2 * np.pi * 0.5 * np.arange(n) * dt))
    ramp = np.linspace(-2.0, 2.0, n)
    dead = {"name": "deadzone", "at": "u", "row": None, "params": {"width": 0.5}}
    assert "linear model" in ip._not_shown(ip._Run(plant, dt, n, two_level, None, None, ["x", "v"]), dead)
    assert ip._not_shown(ip._Run(plant, dt, n, ramp, None, None, ["x", "v"]), dead) is None


def test_a_cogging_its_position_never_turns_two_periods_of_is_drawn_again():
    plant = ip.Plant("single", {"m": 1.0, "b": 1.0, "k": 0.0})
    dt, n = 1e-2, 400
    u = np.full(n, 1.0)  # x travels about 3 m in 4 s
    run = ip._Run(plant, dt, n, u, None, None, ["x", "v"])
    travel = float(np.ptp(run.run([])[0][:, 0]))
    few = {"name": "cogging", "at": "x", "row": "v", "params": {"amplitude": 0.05, "periods": 3.0 / travel,
                                                                 "phase": 0.0}}
    many = {**few, "params": {**few["params"], "periods": 30.0 / travel}}
    assert "periods" in ip._not_shown(run, few)
    assert ip._not_shown(run, many) is None


def test_the_oracle_base_is_the_record_plant_without_its_effects(record):
    """benchmarks/bench_diagnosis_oracle.py gives the diagnosis the simulator's own linear plant as a cosim model:
    simulated by cosim on the record's input, it follows the simulator's run without the effect."""
    import bench_diagnosis_oracle as oracle

    spec = record.spec
    plant = ip.Plant(spec["plant"]["kind"], {k: v for k, v in spec["plant"].items() if k != "kind"})
    model = oracle.linear_plant(spec, record.cli)
    assert model.is_linear and len(model.states) == len(plant.states)
    u = record.train[plant.input][:-1]
    without, _ = ip.simulate(plant, [], spec["dt"], len(u), u=u)
    sim = model.simulate(without[0], u[:, None], dt=spec["dt"])
    assert sim.ok
    for i in range(len(plant.states)):
        assert np.max(np.abs(sim.states[:, i] - without[:, i])) < 1e-3 * np.ptp(without[:, i])


def test_the_told_path_names_the_true_effects_at_their_true_nuisance_values():
    """Path (e) of benchmarks/bench_diagnosis_oracle.py tells ``cosim diagnose --effects`` the record's effects, each
    at its true nuisance value in cosim's units (a delay in samples), in a selection cosim parses."""
    import bench_diagnosis_oracle as oracle

    from cosim.diagnose.effects import effect_selection

    spec = {"dt": 0.002, "effects": [
        {"name": "delay", "params": {"delay_s": 0.0286}},
        {"name": "cogging", "params": {"amplitude": 0.1, "periods": 17.0, "phase": 0.3}},
        {"name": "stribeck", "params": {"Fs": 1.0, "vs": 0.25, "eps": 1e-3}},
        {"name": "gravity", "params": {"G": 2.0}}]}
    told = oracle.told_effects(spec)
    assert told == "delay:delay=14,cogging:periods=17,stribeck:vs=0.25,gravity"
    parsed = effect_selection(told)
    assert parsed.fixed == {"delay": 14.0, "cogging": 17.0, "stribeck": 0.25}
    assert list(parsed.names) == ["delay", "cogging", "stribeck", "gravity"]
    assert oracle.told_effects({"dt": 0.002, "effects": []}) == "all"


def test_the_oracle_bench_takes_the_held_out_call_of_the_generalisation_bench():
    """The oracle bench replaces the generalisation bench's held-out figures with its own (paths (o) and (oe)
    against the oracle base); the run calls it as the generalisation bench's, so it must take every argument
    that one takes (it did not once: every held-out figure of the oracle paths was lost to a TypeError)."""
    import inspect

    import bench_diagnosis_generalization as gen
    import bench_diagnosis_oracle as oracle

    ours = inspect.signature(oracle.heldout_figures).parameters
    assert list(inspect.signature(oracle._heldout_figures).parameters) == list(ours)
    assert list(inspect.signature(gen.heldout_figures).parameters) == list(ours)
