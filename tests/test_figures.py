"""Figures people read: every plot function returns a matplotlib Figure (a PNG only when given a path), with units
on the axes, one colour per role in every figure (cosim.figures.COLOURS), measured data thin and on top, error
panels under comparisons; and the results with a report show as a small HTML table in Jupyter."""

import numpy as np
import pytest
from diagnose_fixtures import coulomb_mass, write_csv
from loop_fixtures import StateFeedback
from matplotlib.colors import same_color
from matplotlib.figure import Figure
from summary_checks import summary_rows

from cosim.data.datafile import load_data
from cosim.data.plots import plot_trajectory
from cosim.data.trajectory import Trajectory
from cosim.diagnose import diagnose
from cosim.figures import COLOURS, axis_label, binned_mean, new_figure
from cosim.identify.compare import compare
from cosim.identify.model import IdentifiedModel
from cosim.loop.closed_loop import closed_loop
from cosim.loop.plots import plot_closed_loop
from cosim.report import Report, html_table, value_with_error
from cosim.study.reproduce import plot_r2_vs_noise

PNG = b"\x89PNG\r\n\x1a\n"


def is_png(path) -> bool:
    return path.read_bytes()[:8] == PNG


def line(ax, label):
    return next(artist for artist in ax.get_lines() if artist.get_label() == label)


@pytest.fixture(scope="module")
def loop(fmu):
    """A short closed loop on the FMU with the controller's design model run beside it."""
    return closed_loop(StateFeedback(), fmu, duration=0.4, reference={"theta_L": 0.01}, progress=False)


@pytest.fixture(scope="module")
def friction_diagnosis():
    """A noise-free mass with Coulomb friction, and its diagnosis (diagnose_fixtures.coulomb_mass)."""
    data, linear = coulomb_mass()
    return diagnose(linear, data)


def test_the_palette_and_the_helpers():
    assert {"measured", "fmu", "model", "before", "after", "reference", "limit"} <= set(COLOURS)
    assert len({COLOURS[k] for k in ("measured", "model", "before", "after", "other")}) == 5
    assert axis_label("Tm", "N.m") == "Tm [N m]" and axis_label("x") == "x"
    centre, mean, std, count = binned_mean(np.linspace(-1, 1, 2001), np.sign(np.linspace(-1, 1, 2001)), bins=10)
    assert len(centre) == 10 and mean[0] == -1.0 and mean[-1] == 1.0 and std[0] == 0.0 and count.sum() == 2001
    assert new_figure().canvas.manager is None  # outside pyplot: nothing to close, no backend switched


def test_plot_trajectory_draws_the_data_on_top_skips_zero_signals_and_draws_a_shared_input_once(tmp_path):
    t = np.linspace(0.0, 1.0, 201)
    u = np.sign(np.sin(2 * np.pi * 3 * t))
    data = Trajectory.from_arrays(t, {"Tm": u, "TL": 0 * t, "theta": np.sin(t) + 0.01 * np.cos(40 * t)},
                                  units={"Tm": "N.m", "TL": "N.m", "theta": "rad"},
                                  roles={"Tm": "input", "TL": "input", "theta": "output"})
    model = Trajectory.from_arrays(t, {"Tm": u, "TL": 0 * t, "theta": np.sin(t)}, units={"theta": "rad"},
                                   roles={"Tm": "input", "TL": "input"})
    fig = plot_trajectory(data, tmp_path / "t.png", label="measured", errors=True, title="run",
                          others=[("model", model, COLOURS["before"])])
    assert isinstance(fig, Figure) and is_png(tmp_path / "t.png")
    assert [ax.get_ylabel() for ax in fig.axes] == ["Tm\n[N m]", "theta\n[rad]", "error\n[rad]"]
    assert fig.axes[-1].get_xlabel() == "time [s]"
    assert "TL is zero throughout: not drawn" in fig.get_suptitle()
    tm, theta, error = fig.axes
    assert len(tm.get_lines()) == 1 and "the same in model" in tm.get_title(loc="right")   # drawn once
    measured, model_line = line(theta, "measured"), line(theta, "model")
    assert same_color(measured.get_color(), COLOURS["measured"]) and same_color(model_line.get_color(),
                                                                                COLOURS["before"])
    assert measured.get_zorder() > model_line.get_zorder() and measured.get_linewidth() < model_line.get_linewidth()
    np.testing.assert_allclose(error.get_lines()[0].get_ydata(), 0.01 * np.cos(40 * t))
    assert all(text.get_fontsize() >= 9 for text in fig.legends[0].get_texts())
    assert isinstance(plot_trajectory(data), Figure) and [p.name for p in tmp_path.iterdir()] == ["t.png"]


def test_plot_closed_loop_has_units_the_palette_and_an_error_panel(loop, tmp_path):
    fig = plot_closed_loop(loop, tmp_path / "loop.png", title="step")   # the old positional path still writes
    assert isinstance(fig, Figure) and is_png(tmp_path / "loop.png")
    assert [ax.get_ylabel() for ax in fig.axes] == ["theta_L [rad]", "FMU −\nmodel [rad]", "Tm [N m]\n(control)",
                                                    "compute time\n[µs/call]"]
    assert fig.axes[-1].get_xlabel() == "time [s]"
    top = fig.axes[0]
    fmu, model = line(top, "FMU"), line(top, "design model")
    assert same_color(fmu.get_color(), COLOURS["fmu"]) and same_color(model.get_color(), COLOURS["model"])
    assert fmu.get_zorder() > model.get_zorder()
    assert all(text.get_fontsize() >= 9 for text in top.get_legend().get_texts())
    k = min(len(loop.model), len(loop.fmu))
    np.testing.assert_allclose(fig.axes[1].get_lines()[0].get_ydata(),
                               loop.fmu["theta_L"][:k] - loop.model["theta_L"][:k])
    assert plot_closed_loop(loop, path=tmp_path / "kw.png").axes and is_png(tmp_path / "kw.png")


def test_the_measured_line_has_one_colour_in_every_figure(loop, tmp_path):
    t = np.arange(400) * 0.01
    u = np.sin(2 * np.pi * 0.3 * t)
    x = np.zeros_like(t)
    for k in range(len(t) - 1):
        x[k + 1] = np.exp(-0.01) * x[k] + (1 - np.exp(-0.01)) * u[k]
    record = Trajectory.from_arrays(t, {"x": x, "u": u}, units={"x": "m"}, roles={"x": "state", "u": "input"})
    model = IdentifiedModel(states=("x",), inputs=("u",), terms=("x", "u"), coef=np.array([[-1.1, 1.0]]))
    comparison = compare(model, record).plot(tmp_path / "c.png")
    assert is_png(tmp_path / "c.png") and [ax.get_ylabel() for ax in comparison.axes] == ["x [m]", "error [m]"]
    colours = [line(comparison.axes[0], "measured").get_color(),
               line(plot_trajectory(record).axes[1], "data").get_color(),
               line(plot_closed_loop(loop).axes[0], "FMU").get_color()]
    assert all(same_color(c, COLOURS["measured"]) for c in colours)


def test_the_diagnosis_figures_and_its_html(friction_diagnosis, tmp_path):
    report = friction_diagnosis
    fig = report.plot_evidence(tmp_path / "e.png")
    assert isinstance(fig, Figure) and is_png(tmp_path / "e.png")
    equation, free_run = fig.axes
    assert equation.get_xlabel() == "v [m/s]" and equation.get_ylabel() == "equation residual of v' [m/s²]"
    assert free_run.get_ylabel() == "free-run residual of v [m/s]"
    # binned means with error bars, not a scatter cloud: the step at zero speed, gone after
    before, after = equation.containers
    assert before.get_label().startswith("before") and len(before.lines[0].get_xdata()) <= 30
    means = before.lines[0].get_ydata()
    assert means[0] > 0.5 and means[-1] < -0.5 and np.max(np.abs(after.lines[0].get_ydata())) < 0.2
    assert same_color(before.lines[0].get_color(), COLOURS["before"])
    assert same_color(after.lines[0].get_color(), COLOURS["after"])
    runs = report.plot_free_run(tmp_path / "f.png")
    assert is_png(tmp_path / "f.png")
    assert [ax.get_ylabel() for ax in runs.axes] == ["x\n[m]", "error\n[m]", "v\n[m/s]", "error\n[m/s]"]
    assert same_color(line(runs.axes[0], "model after").get_color(), COLOURS["after"])
    text = report._repr_html_()
    assert "<table>" in text and "coulomb_friction" in text and "NRMSE %" in text and "Fc" in text


def test_the_diagnosis_report_opens_with_its_summary(friction_diagnosis, tmp_path):
    report = friction_diagnosis
    data = report.data
    csv = write_csv(tmp_path / "mass.csv", {"t": data.time, **{name: data[name] for name in ("x", "v", "u")}})
    path = report.write_report(tmp_path / "diagnosis.html", seconds=4.5, records=[load_data(csv, time="t")],
                               model_from="from linear.json")
    rows = summary_rows(path)
    assert rows["Plant"] == "measured data: mass.csv (no plant model: the diagnosis reads the data alone)"
    assert rows["Data"].startswith("mass.csv: 3001 samples, 3 s at 1 ms (1000 Hz); noise, estimated from second "
                                   "differences, % of each state's std: x ")
    assert rows["Model"] == "from linear.json: 2 states (x, v), inputs u, 3 terms"
    fc = report.effects[0]
    assert rows["Found"].startswith("coulomb_friction on v: Fc = "
                                    + value_with_error(fc.parameters["Fc"], fc.uncertainty["Fc"]))
    figures = [[report.before["per_state"][s]["nrmse_pct"] for s in ("x", "v")] + [report.before["nrmse_pct"]],
               [report.after["per_state"][s]["nrmse_pct"] for s in ("x", "v")] + [report.after["nrmse_pct"]]]
    numbers = [" ".join(f"{float(f'{v:.3g}'):.6g}" for v in row) for row in figures]
    assert rows["Error"] == ("free-run NRMSE, % of each state's spread, against the data (lower is better) x v mean "
                             f"before {numbers[0]} after {numbers[1]}")
    assert rows["Time"] == "4.5 s" and "Verdicts" not in rows


def test_the_r2_figure_shows_the_misfit_on_a_log_scale(tmp_path):
    summary = {"noise_levels": [0.0, 0.1, 0.3], "r2": {s: [0.99999, 0.9995, 0.995]
                                                         for s in ("theta_m", "omega_m", "theta_L", "omega_L")}}
    fig = plot_r2_vs_noise(summary, tmp_path / "r2.png")
    assert is_png(tmp_path / "r2.png")
    ax = fig.axes[0]
    assert ax.get_yscale() == "log" and ax.get_ylabel().startswith("1 − R²")
    assert ax.get_xlabel() == "noise level [% of each state's std]"
    np.testing.assert_allclose(ax.get_lines()[0].get_ydata(), [1e-5, 5e-4, 5e-3], rtol=1e-6)


def test_a_report_embeds_a_figure_and_tables_render_alone(tmp_path):
    fig = new_figure()
    fig.subplots().plot([0, 1], [1, 0])
    report = Report("r")
    report.add_figure("a figure", fig, caption="drawn in memory")
    assert "data:image/png;base64" in report.render()
    assert html_table([{"a": 1.0}], highlight={(0, "a"): True}).startswith("<table>")
