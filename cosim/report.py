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
import io
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .files import write_text_atomic

__all__ = ["Report", "html_table"]

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
                f"</title><style>{_STYLE}</style></head><body><h1>{html.escape(self.title)}</h1>{sub}"
                + "\n".join(self._parts)
                + f"<p class=\"note\">Written by cosim on {stamp}.</p></body></html>\n")

    def write(self, path: str | os.PathLike) -> Path:
        """Write the report atomically and return its path."""
        return write_text_atomic(path, self.render())
