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
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .files import write_text_atomic

__all__ = ["Report"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { border-bottom: 2px solid #444; } h2 { margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
.good { background: #e3f6e3; } .bad { background: #fbe3e3; }
figure { margin: 1em 0; } figcaption { font-size: 0.85em; color: #555; }
img { max-width: 100%; } .note { color: #555; font-size: 0.9em; }
"""


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return html.escape(str(value))


class Report:
    """An HTML report built section by section, written atomically as one file."""

    def __init__(self, title: str, *, subtitle: str = "") -> None:
        self.title = title
        self.subtitle = subtitle
        self._parts: list[str] = []

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
        if hasattr(rows, "to_dict"):
            rows = rows.reset_index().to_dict("records") if rows.index.name else rows.to_dict("records")
        rows = list(rows)
        if heading:
            self._parts.append(f"<h2>{html.escape(heading)}</h2>")
        if not rows:
            self._parts.append("<p>(no rows)</p>")
            return
        columns = list(dict.fromkeys(key for row in rows for key in row))
        head = "".join(f"<th>{html.escape(str(c))}</th>" for c in columns)
        body = []
        for i, row in enumerate(rows):
            cells = []
            for c in columns:
                mark = (highlight or {}).get((i, c))
                css = "" if mark is None else (' class="good"' if mark else ' class="bad"')
                cells.append(f"<td{css}>{_cell(row.get(c, ''))}</td>")
            body.append("<tr>" + "".join(cells) + "</tr>")
        cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
        self._parts.append(f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>")

    def add_figure(self, heading: str | None, png: str | os.PathLike, *, caption: str = "") -> None:
        """A PNG file, embedded."""
        data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
        if heading:
            self._parts.append(f"<h2>{html.escape(heading)}</h2>")
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self._parts.append(f'<figure><img alt="{html.escape(Path(png).name)}" src="data:image/png;base64,{data}">'
                           f"{cap}</figure>")

    def render(self) -> str:
        stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        sub = f"<p>{html.escape(self.subtitle)}</p>" if self.subtitle else ""
        return (f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(self.title)}"
                f"</title><style>{_STYLE}</style></head><body><h1>{html.escape(self.title)}</h1>{sub}"
                + "\n".join(self._parts)
                + f"<p class=\"note\">Written by cosim on {stamp}.</p></body></html>\n")

    def write(self, path: str | os.PathLike) -> Path:
        """Write the report atomically and return its path."""
        return write_text_atomic(path, self.render())
