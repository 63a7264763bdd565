"""One self-contained HTML report per job: headings, text, tables and PNG figures embedded in the file.

Written by hand on purpose: a report is a few sections of tables and pictures, and a template engine would
be a dependency for forty lines of HTML. Everything is escaped; figures are inlined as base64 so the file can
be mailed or archived alone.

Examples
--------
>>> import tempfile, pathlib
>>> report = Report("Demo")
>>> report.add_text("Summary", "Everything passed.")
>>> report.add_table("Figures", [{"state": "theta_m", "r2": 0.999}])
>>> path = report.write(pathlib.Path(tempfile.mkdtemp()) / "report.html")
>>> "<table" in path.read_text()
True

Every report opens with a summary box (:func:`summary_box`, placed by :meth:`Report.add_summary` right under the
title wherever the call comes): the plant, the data, what was found, the error before and after, the verdicts
and the time the job took, each where it applies.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .files import write_text_atomic

__all__ = ["Report", "duration_text", "html_table", "step_text", "summary_box", "value_with_error"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
.good { background: #e3f6e3; } .bad { background: #fbe3e3; }
figure { margin: 1em 0; } figcaption { font-size: 0.85em; color: #555; }
img { max-width: 100%; } .note { color: #555; font-size: 0.9em; }
.summary { border: 1px solid #b8c4d0; border-left: 6px solid #5b7fa6; border-radius: 4px; background: #f5f8fb;
  padding: 0.5em 1.1em 0.7em; margin: 1em 0 1.6em; }
.summary.passed { border-left-color: #2e7d32; } .summary.failed { border-left-color: #c62828; }
.summary-head { font-size: 1.15em; font-weight: 600; margin: 0.2em 0 0.4em; }
.summary dl { display: grid; grid-template-columns: 8.5em 1fr; gap: 0.35em 1em; margin: 0; }
.summary dt { font-weight: 600; color: #345; } .summary dd { margin: 0; }
.summary ul { margin: 0; padding-left: 1.1em; } .summary table { margin: 0.2em 0; font-size: 0.88em; }
.summary .what { color: #555; font-size: 0.88em; } .summary .verdicts td:not(:first-child) { text-align: center; }
.badge { display: inline-block; padding: 0 0.45em; border-radius: 3px; font-size: 0.85em; font-weight: 600;
  color: #fff; background: #777; } .badge.pass { background: #2e7d32; } .badge.fail { background: #c62828; }
"""


#: Cell colours of a good and a bad mark (inline too, so a notebook shows them without the report's style).
_MARKS = {True: ("good", "#e3f6e3"), False: ("bad", "#fbe3e3")}


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return html.escape(str(value))


def html_table(rows: Sequence[Mapping[str, Any]] | Any, *, caption: str = "",
               highlight: Mapping[tuple[int, str], bool] | None = None) -> str:
    """An HTML table of `rows` (the report's tables, and the ``_repr_html_`` of cosim's results in Jupyter).

    Parameters
    ----------
    rows : sequence of dict, or pandas.DataFrame
        One dict per row; the columns are the keys in the order first seen.
    caption : str
    highlight : mapping of (row index, column) to bool, optional
        Cells marked good (True, green) or bad (False, red).

    Returns
    -------
    str

    Examples
    --------
    >>> html_table([{"state": "x", "r2": 0.5}], caption="fit", highlight={(0, "r2"): False})
    '<table><caption>fit</caption><thead><tr><th>state</th><th>r2</th></tr></thead><tbody><tr><td>x</td><td \
class="bad" style="background:#fbe3e3">0.5</td></tr></tbody></table>'
    """
    if hasattr(rows, "to_dict"):
        rows = rows.reset_index().to_dict("records") if rows.index.name else rows.to_dict("records")
    rows = list(rows)
    if not rows:
        return "<p>(no rows)</p>"
    columns = list(dict.fromkeys(key for row in rows for key in row))
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in columns)
    body = []
    for i, row in enumerate(rows):
        cells = []
        for c in columns:
            mark = (highlight or {}).get((i, c))
            css = "" if mark is None else ' class="{}" style="background:{}"'.format(*_MARKS[bool(mark)])
            cells.append(f"<td{css}>{_cell(row.get(c, ''))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def value_with_error(value: float, error: float | None = None, unit: str = "") -> str:
    """`value` ± its standard error, rounded to the error's second significant digit (``99.34 ± 0.62``).

    Examples
    --------
    >>> value_with_error(99.3412, 0.6213, "N m"), value_with_error(0.0010234, 3.1e-5), value_with_error(2.5)
    ('99.34 ± 0.62 N m', '0.001023 ± 0.000031', '2.5')
    >>> value_with_error(12345.0, 151.0)
    '12340 ± 150'
    """
    unit = f" {unit}" if unit else ""
    if error is None or not math.isfinite(error) or error <= 0 or not math.isfinite(value):
        return f"{value:.5g}{unit}"
    decimals = 1 - math.floor(math.log10(error))
    if abs(value) >= 1e7 or not -6 <= decimals <= 8:
        return f"{value:.4g} ± {error:.2g}{unit}"
    if decimals < 0:  # (12345 ± 151 -> 12340 ± 150)
        return f"{round(value, decimals):.0f} ± {round(error, decimals):.0f}{unit}"
    return f"{value:.{decimals}f} ± {error:.{decimals}f}{unit}"


def duration_text(seconds: float) -> str:
    """Seconds as a reader says them: ``0.82 s``, ``22.3 s``, ``3 min 12 s``, ``1 h 05 min``."""
    if seconds < 10:
        return f"{seconds:.2g} s" if seconds < 1 else f"{seconds:.1f} s"
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, sec = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {sec:02d} s"
    return f"{minutes // 60} h {minutes % 60:02d} min"


def step_text(dt: float) -> str:
    """A sample time with its rate: ``0.443 ms (2257 Hz)``, ``10 ms (100 Hz)``, ``2 s (0.5 Hz)``."""
    value = f"{dt * 1e3:.3g} ms" if dt < 1 else f"{dt:.3g} s"
    return f"{value} ({1.0 / dt:.4g} Hz)" if dt > 0 else value


def _badge(passed: bool | None, text: str | None = None) -> str:
    css = {True: " pass", False: " fail", None: ""}[passed]
    label = text or {True: "PASSED", False: "FAILED", None: "n/a"}[passed]
    return f'<span class="badge{css}">{html.escape(label)}</span>'


def _effect_line(effect: Mapping[str, Any]) -> str:
    units, truth = effect.get("units") or {}, effect.get("truth") or {}
    errors = effect.get("uncertainty") or {}
    params = []
    for name, value in (effect.get("parameters") or {}).items():
        text = f"{name} = {value_with_error(float(value), errors.get(name), units.get(name, ''))}"
        if name in truth:
            text += f" (true {truth[name]:g}{' ' + units[name] if units.get(name) else ''})"
        params.append(html.escape(text))
    where = f" on {html.escape(str(effect['attached_to']))}" if effect.get("attached_to") else ""
    meaning = f'<br><span class="what">{html.escape(effect["meaning"])}</span>' if effect.get("meaning") else ""
    return (f"<li><b>{html.escape(str(effect['name']))}</b>{where}: {', '.join(params) or 'no parameter'}"
            f"{meaning}</li>")


def _errors_table(errors: Mapping[str, Mapping[str, float | None]]) -> str:
    """Rows (before, after...) by signals; a later row's cell is green where it is lower than the first row's, red
    where it is higher (as shown, to three digits: an unchanged figure is not marked)."""
    labels = list(errors)
    signals = list(dict.fromkeys(k for values in errors.values() for k in values))
    rows = [{"": label, **{k: "n/a" if errors[label].get(k) is None else float(f"{errors[label][k]:.3g}")
                           for k in signals}} for label in labels]
    marks = {(i, k): rows[i][k] < rows[0][k] for i in range(1, len(rows)) for k in signals
             if "n/a" not in (rows[i][k], rows[0][k]) and rows[i][k] != rows[0][k]}
    return html_table(rows, highlight=marks)


def _verdicts_table(verdicts: Sequence[Mapping[str, Any]]) -> str:
    columns = list(dict.fromkeys(name for v in verdicts for name in (v.get("scenarios") or {})))
    head = "".join(f"<th>{html.escape(c)}</th>" for c in ["", *columns, "verdict"])
    body = []
    for v in verdicts:
        cells = [html.escape(str(v["label"]))]
        cells += [_badge(v["scenarios"][c]) if c in (v.get("scenarios") or {}) else "" for c in columns]
        note = f' <span class="what">{html.escape(v["note"])}</span>' if v.get("note") else ""
        cells.append(_badge(v.get("passed")) + note)
        body.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return f'<table class="verdicts"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'


def summary_box(*, plant: str | None = None, data: str | None = None, context: Sequence[tuple[str, str]] = (),
                effects: Sequence[Mapping[str, Any]] | None = None, no_effect: str = "",
                errors: Mapping[str, Mapping[str, float | None]] | None = None, error_label: str = "",
                verdicts: Sequence[Mapping[str, Any]] | None = None, robustness: Mapping[str, Any] | None = None,
                more: Sequence[tuple[str, str]] = (), seconds: float | None = None,
                timing: Mapping[str, float] | None = None) -> str:
    """The box a report opens with: what the job ran on, what it found, how the error moved, the verdicts, the time.

    Every field is optional: a row shows only where it applies (a validation finds no effect; a diagnosis has no
    verdict). All text is escaped.

    Parameters
    ----------
    plant : str, optional
        The plant: the FMU (name, FMI version, interface, parameters set), or the data file of measured data.
    data : str, optional
        The data: file, samples, duration, step, noise.
    context : sequence of (label, text)
        More rows after the data (the model diagnosed, the controller validated, the scenarios).
    effects : sequence of dict, optional
        What was found, each as :meth:`cosim.diagnose.EffectCandidate.to_dict` gives it: ``name``,
        ``attached_to``, ``parameters``, ``uncertainty`` (standard errors by parameter), ``meaning``; optionally
        ``units`` and ``truth`` (by parameter). An empty sequence shows "no effect found" and `no_effect`
        (why); None leaves the row out.
    errors : mapping of row label to {signal: value}, optional
        The error before and after (or any rows compared with the first), by signal: a later row's cell is green
        where it is lower than the first row's, red where it is higher.
    error_label : str
        What `errors` measures, e.g. "free-run NRMSE, % (lower is better)".
    verdicts : sequence of dict, optional
        One per controller (or claim): ``label``, ``passed`` (bool or None), ``scenarios`` ({name: bool or
        None}), ``note`` (optional).
    robustness : dict, optional
        ``samples``, ``pass_rate`` (0-1), ``passed`` (met the required rate) and ``text`` (how the plants were
        drawn, the worst case).
    more : sequence of (label, text)
        Rows after the verdicts.
    seconds : float, optional
        How long the job took (measured where it ran).
    timing : mapping of str to float, optional
        Seconds of its parts worth naming, e.g. ``{"diagnosis": 10.2}``.

    Returns
    -------
    str
        A ``<section class="summary">``; its style is in the report's.

    Examples
    --------
    >>> box = summary_box(plant="servo.fmu", effects=[{"name": "coulomb_friction", "attached_to": "omega_m",
    ...                   "parameters": {"Fc": 99.34}, "uncertainty": {"Fc": 0.62}}],
    ...                   errors={"before": {"x": 6.4}, "after": {"x": 0.16}}, seconds=22.3)
    >>> "Fc = 99.34 ± 0.62" in box and "22.3 s" in box
    True
    """
    rows: list[tuple[str, str]] = []
    if plant:
        rows.append(("Plant", html.escape(plant)))
    if data:
        rows.append(("Data", html.escape(data)))
    rows += [(label, html.escape(text)) for label, text in context]
    if effects is not None:
        found = "".join(_effect_line(e) for e in effects) if effects else \
            "<li><b>no effect found</b>" + (f": {html.escape(no_effect)}" if no_effect else "") + "</li>"
        rows.append(("Found", f"<ul>{found}</ul>"))
    if errors:
        label = f'<span class="what">{html.escape(error_label)}</span>' if error_label else ""
        rows.append(("Error", label + _errors_table(errors)))
    if verdicts:
        rows.append(("Verdicts", _verdicts_table(verdicts)))
    if robustness is not None:
        rate = robustness["pass_rate"]
        rows.append(("Robustness", f"{_badge(robustness.get('passed'), f'pass rate {rate:.1%}')} "
                                   f"{html.escape(str(robustness.get('text', '')))}"))
    rows += [(label, html.escape(text)) for label, text in more]
    if seconds is not None:
        parts = ", ".join(f"{k} {duration_text(v)}" for k, v in (timing or {}).items())
        rows.append(("Time", html.escape(duration_text(seconds) + (f" ({parts})" if parts else ""))))
    outcome = [v.get("passed") for v in verdicts or ()] + ([robustness.get("passed")] if robustness else [])
    failed = sum(1 for p in outcome if p is False)
    css = "" if not outcome else (" failed" if failed else " passed")
    if len(outcome) > 1:
        badge = " " + _badge(not failed, f"{failed} of {len(outcome)} FAILED" if failed else "ALL PASSED")
    else:
        badge = " " + _badge(not failed) if outcome else ""
    items = "".join(f"<dt>{html.escape(label)}</dt><dd>{text}</dd>" for label, text in rows)
    return (f'<section class="summary{css}" id="summary"><div class="summary-head">Summary{badge}</div>'
            f"<dl>{items}</dl></section>")


class Report:
    """An HTML report built section by section, written atomically as one file."""

    def __init__(self, title: str, *, subtitle: str = "") -> None:
        self.title = title
        self.subtitle = subtitle
        self._parts: list[str] = []
        self._summary = ""

    def add_summary(self, **facts: Any) -> None:
        """The report's summary box (:func:`summary_box`'s keyword arguments): shown under the title, above every
        other section, whenever it is added (a job knows its results, and its time, last)."""
        self._summary = summary_box(**facts)

    def add_text(self, heading: str | None, text: str, *, note: bool = False) -> None:
        """A heading (optional) and paragraphs (blank lines separate them)."""
        if heading:
            self._parts.append(f"<h2>{html.escape(heading)}</h2>")
        css = ' class="note"' if note else ""
        for para in str(text).split("\n\n"):
            self._parts.append(f"<p{css}>{html.escape(para)}</p>")

    def add_table(self, heading: str | None, rows: Sequence[Mapping[str, Any]] | Any, *, caption: str = "",
                  highlight: Mapping[tuple[int, str], bool] | None = None) -> None:
        """A table from a list of dicts (or a pandas DataFrame); `highlight` marks cells good/bad."""
        if heading:
            self._parts.append(f"<h2>{html.escape(heading)}</h2>")
        self._parts.append(html_table(rows, caption=caption, highlight=highlight))

    def add_figure(self, heading: str | None, png: str | os.PathLike | Any, *, caption: str = "",
                   alt: str | None = None) -> None:
        """A figure, embedded: a PNG file, or a matplotlib Figure (rendered as PNG in memory).

        Parameters
        ----------
        heading : str or None
        png : path-like or matplotlib.figure.Figure
        caption : str
        alt : str, optional
            The image's alternative text (default: the file's name, or "figure").
        """
        if hasattr(png, "savefig"):
            buffer = io.BytesIO()
            png.savefig(buffer, format="png", dpi=110)
            raw, name = buffer.getvalue(), "figure"
        else:
            raw, name = Path(png).read_bytes(), Path(png).name
        data = base64.b64encode(raw).decode("ascii")
        if heading:
            self._parts.append(f"<h2>{html.escape(heading)}</h2>")
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self._parts.append(f'<figure><img alt="{html.escape(alt or name)}" src="data:image/png;base64,{data}">'
                           f"{cap}</figure>")

    def render(self) -> str:
        stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        sub = f"<p>{html.escape(self.subtitle)}</p>" if self.subtitle else ""
        return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(self.title)}"
                f"</title><style>{_STYLE}</style></head><body><h1>{html.escape(self.title)}</h1>{self._summary}{sub}"
                + "\n".join(self._parts)
                + f"<p class=\"note\">Written by cosim on {stamp}.</p></body></html>\n")

    def write(self, path: str | os.PathLike) -> Path:
        """Write the report atomically and return its path."""
        return write_text_atomic(path, self.render())
