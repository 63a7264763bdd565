"""Building the bundled FMU from C: validity, caching, errors, and a physics check that can fail."""

from __future__ import annotations

import os
import shutil
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu

import cosim.plant.build
from cosim.errors import BuildError, FmuNotFoundError, InvalidSettingError
from cosim.plant.build import build_fmu, fmu_cache_dir, fmu_source_dir

VERSIONS = ("2.0", "3.0")
JM, JL = 250.0, 1000.0


@pytest.fixture(scope="session")
def cache(tmp_path_factory) -> str:
    return str(tmp_path_factory.mktemp("fmu-cache"))


@pytest.fixture(scope="session")
def fmus(cache) -> dict[str, str]:
    """One build per FMI version for the whole session."""
    return {v: str(build_fmu(fmi_version=v, cache_dir=cache)) for v in VERSIONS}


@pytest.mark.parametrize("version", VERSIONS)
def test_fmpy_validation_finds_no_problem(fmus, version):
    assert validate_fmu(fmus[version]) == []


@pytest.mark.parametrize("version", VERSIONS)
def test_fmu_layout(fmus, cache, version):
    path = Path(fmus[version])
    assert path.name == "two_mass_servo.fmu"
    assert path.parent.parent == Path(cache) / "fmus"
    assert path.parent.name.startswith(f"two_mass_servo-fmi{version[0]}-")
    assert len(path.parent.name.rsplit("-", 1)[1]) == 16
    folder = fmpy.platform if version == "2.0" else fmpy.platform_tuple
    names = zipfile.ZipFile(path).namelist()
    assert "modelDescription.xml" in names
    assert f"binaries/{folder}/two_mass_servo{fmpy.sharedLibraryExtension}" in names
    assert {"sources/model.c", "sources/model.h", f"sources/fmi{version[0]}.c"} <= set(names)
    other = "fmi3.c" if version == "2.0" else "fmi2.c"
    assert f"sources/{other}" not in names
    md = fmpy.read_model_description(str(path))
    assert md.fmiVersion == version
    assert md.coSimulation.modelIdentifier == "two_mass_servo"
    # the four outputs are discoverable as states through the declared derivatives
    states = sorted(d.variable.derivative.name for d in md.derivatives)
    assert states == ["omega_L", "omega_m", "theta_L", "theta_m"]
    # nothing but the FMU in its folder: temporary files were renamed or removed
    assert os.listdir(path.parent) == ["two_mass_servo.fmu"]


def test_cache_is_reused(fmus, cache):
    first = Path(fmus["2.0"])
    mtime = first.stat().st_mtime_ns
    again = build_fmu(fmi_version="2.0", cache_dir=cache)
    assert again == first
    assert again.stat().st_mtime_ns == mtime


def test_versions_get_different_keys(fmus):
    assert os.path.dirname(fmus["2.0"]) != os.path.dirname(fmus["3.0"])


def test_source_change_gives_a_new_key(fmus, cache, tmp_path, monkeypatch):
    changed = tmp_path / "two_mass_servo"
    shutil.copytree(fmu_source_dir(), changed)
    with open(changed / "model.c", "a") as fh:
        fh.write("\n/* a change */\n")
    monkeypatch.setattr(cosim.plant.build, "fmu_source_dir", lambda name="two_mass_servo": changed)
    rebuilt = build_fmu(fmi_version="2.0", cache_dir=cache)
    assert rebuilt.is_file()
    assert rebuilt.parent != Path(fmus["2.0"]).parent
    assert validate_fmu(str(rebuilt)) == []


def test_no_compiler_is_a_build_error(tmp_path, monkeypatch):
    empty = tmp_path / "empty-bin"
    empty.mkdir()
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", str(empty))
    with pytest.raises(BuildError, match="^no C compiler found: install gcc or set CC$"):
        build_fmu(cache_dir=tmp_path / "cache", force=True)
    assert not (tmp_path / "cache" / "fmus").exists() or not any((tmp_path / "cache" / "fmus").rglob("*.fmu"))


def test_compiler_errors_are_reported_and_leave_nothing(tmp_path, monkeypatch):
    broken = tmp_path / "two_mass_servo"
    shutil.copytree(fmu_source_dir(), broken)
    with open(broken / "model.c", "a") as fh:
        fh.write("\nthis is not C;\n")
    monkeypatch.setattr(cosim.plant.build, "fmu_source_dir", lambda name="two_mass_servo": broken)
    with pytest.raises(BuildError, match="error") as info:
        build_fmu(cache_dir=tmp_path / "cache")
    assert "\n" not in str(info.value)
    assert not list((tmp_path / "cache").rglob("*.fmu*"))


def test_bad_arguments():
    with pytest.raises(InvalidSettingError):
        build_fmu(fmi_version="1.0")
    with pytest.raises(FmuNotFoundError):
        build_fmu("no_such_model")
    with pytest.raises(InvalidSettingError):
        fmu_source_dir("../etc")


def test_cache_dir_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("COSIM_CACHE_DIR", str(tmp_path / "c"))
    assert fmu_cache_dir() == tmp_path / "c"
    monkeypatch.delenv("COSIM_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert fmu_cache_dir() == tmp_path / "xdg" / "cosim"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert fmu_cache_dir() == Path.home() / ".cache" / "cosim"


@pytest.mark.parametrize("version", VERSIONS)
def test_start_values_in_the_xml_match_the_c_defaults(fmus, version):
    """Instantiate, read every variable back before initialisation, compare with the XML start values."""
    path = fmus[version]
    md = fmpy.read_model_description(path)
    fmu = fmpy.instantiate_fmu(fmpy.extract(path), md)
    try:
        for v in md.modelVariables:
            if v.start is None:
                continue
            if v.type in ("Integer", "Int32"):
                got = (fmu.getInteger if version == "2.0" else fmu.getInt32)([v.valueReference])[0]
            else:
                got = (fmu.getReal if version == "2.0" else fmu.getFloat64)([v.valueReference])[0]
            assert got == float(v.start), v.name
    finally:
        fmu.freeInstance()


@pytest.mark.parametrize("version", VERSIONS)
def test_constant_torque_gives_the_rigid_body_motion(fmus, version):
    """With Bm = 0 and TL = 0 the coupling torques cancel: the total momentum Jm*wm + JL*wL grows as Tm*t and
    Jm*thm + JL*thL as Tm*t^2/2 + (momentum at 0)*t, whatever the oscillation of the spring (RK4 keeps these
    linear invariants exactly). The states also start from the start values set by name."""
    tm, dt = 1000.0, 1e-3
    start = {"theta_m": 0.3, "omega_m": 0.0, "theta_L": 0.3002, "omega_L": 0.05}
    res = fmpy.simulate_fmu(
        fmus[version], start_values={"Tm": tm, "Bm": 0.0, **start}, stop_time=0.5, output_interval=dt
    )
    t = res["time"]
    assert t[0] == 0.0 and res["theta_L"][0] == 0.3002 and res["omega_L"][0] == 0.05
    p0 = JL * 0.05
    momentum = JM * res["omega_m"] + JL * res["omega_L"]
    np.testing.assert_allclose(momentum, p0 + tm * t, rtol=1e-10, atol=1e-9)
    centre = JM * res["theta_m"] + JL * res["theta_L"]
    expected = JM * 0.3 + JL * 0.3002 + p0 * t + 0.5 * tm * t**2
    np.testing.assert_allclose(centre, expected, rtol=1e-10, atol=1e-9)
    # steady acceleration of the load: Tm/(Jm + JL) on average (the spring adds a small ripple)
    slope = np.polyfit(t, res["omega_L"], 1)[0]
    assert slope == pytest.approx(tm / (JM + JL), rel=0.01)
    # the spring rings around the twist that transmits JL*a: JL*Tm/(Jm + JL)/KL = 3.2e-4 rad
    twist = res["theta_m"] - res["theta_L"]
    assert np.mean(twist[250:]) == pytest.approx(JL * tm / (JM + JL) / 2.5e6, rel=0.25)
    assert twist.min() < -3e-4 and twist.max() > 9e-4


@pytest.mark.parametrize("version", VERSIONS)
def test_invalid_parameter_is_rejected_with_its_name(fmus, version, capfd):
    with pytest.raises(Exception, match="ExitInitializationMode"):
        fmpy.simulate_fmu(fmus[version], start_values={"Jm": 0.0}, stop_time=0.01)
    assert "parameter Jm = 0 is invalid" in capfd.readouterr().out


@pytest.mark.parametrize("version", VERSIONS)
def test_divergence_is_an_error_status_mid_run(fmus, version, capfd):
    with pytest.raises(Exception, match="DoStep"):
        fmpy.simulate_fmu(
            fmus[version], start_values={"Bm": -1e5, "Tm": 100.0}, stop_time=1.0, output_interval=1e-3
        )
    out = capfd.readouterr().out
    assert "diverged" in out and "from t = 0.092 to t = 0.093" in out
