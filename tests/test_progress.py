"""Progress bars show on a terminal only: never in a file or a pipe, unless the caller asks with ``progress=True``.

The rule (tqdm's ``disable=None``, which asks ``sys.stderr.isatty()``) holds for the sweeps and the Monte Carlo
robustness, the reproduction of the reference study and the demo. A terminal is faked with a text stream whose
``isatty()`` answers True; the redirected case runs the real command line with stderr to a pipe.
"""

from __future__ import annotations

import io
import subprocess
import sys

import pytest

from controllers.pid import PID
from cosim.study.robustness import robustness
from cosim.study.sweep import _example_case, run_sweep

#: What a tqdm bar writes: "desc:  40%|████      | 2/5 [...]".
BAR = "%|"
#: A short closed loop: the samples of the Monte Carlo take a fraction of a second each.
SCENARIO = "step:amp=0.01,at=0.05,duration=0.5"
CASES = [{"level": 0.1, "seed": seed} for seed in range(3)]


class FakeTerminal(io.StringIO):
    """A stderr that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def fake_terminal(monkeypatch) -> FakeTerminal:
    """Replace sys.stderr by a :class:`FakeTerminal` for the rest of the test.

    Called in the test's body: pytest's output capture sets sys.stderr again as each phase of a test starts, so a
    fixture's replacement would not last into the test.
    """
    stream = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", stream)
    return stream


@pytest.fixture(scope="module")
def pid() -> PID:
    """A PID on the load angle of the bundled servo (the gains of the robustness example)."""
    return PID(kp=1.5e4, ki=1.3e4, kd=6.4e3, tf=0.022, b=0.33, dt=1e-3, inputs="Tm", outputs="theta_L",
               u_min=-5000, u_max=5000)


def test_validate_robustness_writes_no_bar_into_a_pipe(fmu, pid, tmp_path):
    # fmu: the bundled FMU built into the cache, so that `bundled` finds it in the child process; stderr and
    # stdout go to pipes (capture_output), as in `cosim validate ... 2> log`
    ctrl = pid.save(tmp_path / "pid.json")
    result = subprocess.run([sys.executable, "-m", "cosim.cli", "validate", "bundled", str(ctrl), "--robustness",
                             "3", "--workers", "1", "--no-model", "--scenario", SCENARIO],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode in (0, 1), result.stderr  # 1: a spec not met, which is not what this test is about
    assert "robustness: 3 samples" in result.stdout
    assert BAR not in result.stderr and "robustness" not in result.stderr, result.stderr


def test_robustness_writes_a_bar_when_asked_and_none_by_default_off_a_terminal(fmu, pid, capsys):
    robustness(fmu, pid, SCENARIO, ["overshoot<=60%"], samples=2, workers=1, progress=True)
    err = capsys.readouterr().err
    assert "robustness" in err and BAR in err and "2/2" in err
    robustness(fmu, pid, SCENARIO, ["overshoot<=60%"], samples=2, workers=1)  # stderr is captured: no terminal
    assert BAR not in capsys.readouterr().err


def test_sweeps_and_robustness_show_a_bar_on_a_terminal(fmu, pid, monkeypatch):
    terminal = fake_terminal(monkeypatch)
    run_sweep(_example_case, CASES, workers=1, desc="noise sweep")
    assert "noise sweep" in terminal.getvalue() and "3/3" in terminal.getvalue()
    robustness(fmu, pid, SCENARIO, ["overshoot<=60%"], samples=2, workers=1)
    assert "robustness" in terminal.getvalue()
    terminal.seek(0)
    terminal.truncate()
    run_sweep(_example_case, CASES, workers=1, progress=False)
    assert terminal.getvalue() == ""


def test_the_reproduction_shows_a_bar_on_a_terminal(monkeypatch, tmp_path):
    import cosim.study.reproduce as reproduce

    terminal = fake_terminal(monkeypatch)

    seen = {}

    class Stop(Exception):
        pass

    def toy_sweep(func, cases, **options):  # the study's bar over toy cases, then stop: the study takes minutes
        seen.update(options)
        run_sweep(_example_case, CASES, **options)
        raise Stop

    monkeypatch.setattr(reproduce, "run_sweep", toy_sweep)
    with pytest.raises(Stop):
        reproduce.reproduce_paper(seeds=1, noise_levels=(0.0,), excitations=("sine",), out_dir=tmp_path, workers=1)
    assert seen["progress"] is None and seen["desc"] == "reproduce paper"
    assert "reproduce paper" in terminal.getvalue() and BAR in terminal.getvalue()


def test_the_demo_shows_its_stages_on_a_terminal_only(monkeypatch, tmp_path):
    import cosim.demo as demo

    terminal = fake_terminal(monkeypatch)

    def stages(out, plant, *, progress, bar, **options):  # the demo's stages, without their work (25 s)
        for stage in demo._STAGES[1:]:
            demo._advance(bar, stage)
        bar.update()
        return {"progress": progress}

    monkeypatch.setattr(demo, "_run_demo", stages)
    assert demo.run_demo(tmp_path) == {"progress": None}
    assert "demo" in terminal.getvalue() and f"{len(demo._STAGES)}/{len(demo._STAGES)}" in terminal.getvalue()
    monkeypatch.setattr(sys, "stderr", io.StringIO())  # redirected: no bar, unless asked for
    demo.run_demo(tmp_path)
    assert sys.stderr.getvalue() == ""
    demo.run_demo(tmp_path, progress=True)
    assert BAR in sys.stderr.getvalue()


@pytest.mark.parametrize("command", ["demo", "validate", ("reproduce", "paper")])
def test_the_commands_leave_the_bar_to_the_terminal_by_default(command):
    from cosim.cli import main

    cmd = main
    for name in (command,) if isinstance(command, str) else command:
        cmd = cmd.commands[name]
    option = next(p for p in cmd.params if p.name == "progress")
    assert option.default is None and option.secondary_opts == ["--no-progress"]
