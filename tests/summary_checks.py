"""Shared by the report tests: a report's summary box, checked to be its first content, row by row as plain text."""

from __future__ import annotations

import html
import re
from pathlib import Path

#: What a self-contained report must not hold: a link to anything outside the file.
EXTERNAL = re.compile(r"""<link|<script|@import|url\(|(?:src|href)\s*=\s*["']?(?:https?:|//|file:)""", re.I)


def plain(fragment: str) -> str:
    """HTML as the text a reader sees (tags dropped, entities read, white space collapsed)."""
    inline = re.sub(r"</?(?:b|i|span)\b[^>]*>", "", fragment)
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", inline))).strip()


def summary_rows(report: str | Path) -> dict[str, str]:
    """The summary box of `report` (an HTML file or its text): its head (``""``) and each row's text by label.

    Checks on the way that the file is self-contained and that the box comes right under the title: nothing but
    the title before it (no section, table, figure or paragraph).
    """
    page = report if isinstance(report, str) else Path(report).read_text(encoding="utf-8")
    external = EXTERNAL.search(page)
    assert external is None, external.group(0)
    body = page.split("<body>", 1)[1]
    title_end = body.index("</h1>") + len("</h1>")
    box = re.match(r'<section class="summary[^"]*" id="summary">(.*?)</section>', body[title_end:], re.S)
    assert box, f"no summary box right under the title: {body[title_end:title_end + 200]!r}"
    rows = {"": plain(re.search(r'<div class="summary-head">(.*?)</div>', box.group(1), re.S).group(1))}
    rows.update((plain(label), plain(text)) for label, text in re.findall(r"<dt>(.*?)</dt><dd>(.*?)</dd>",
                                                                          box.group(1), re.S))
    return rows
