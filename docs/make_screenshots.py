"""Screenshots of the demo's HTML report for the README (docs/screenshots/*.png).

Run from the repository root, after writing a report with ``cosim demo``::

    cosim demo --out-dir /tmp/demo
    python docs/make_screenshots.py --report /tmp/demo/report.html --out docs/screenshots

It needs a Chromium or Google Chrome binary (headless mode, version 112 or later); on
Debian/Ubuntu ``apt-get install chromium``.  It is looked up on the PATH (chromium,
chromium-browser, google-chrome, ...) unless given with ``--browser PATH``.  Pillow
(installed with matplotlib) trims the blank space under each section.  Neither is a
dependency of cosim.

The report has no element ids, so each section is found by its heading text: a copy of the
report in a temporary directory hides what comes before the section (and after it), and
the browser's command-line ``--screenshot`` takes the window.
"""

import argparse
import html
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")

# file name, first heading (text prefix; None = top of the page), heading that ends the
# section (None = end of the page), window height in px
SHOTS = (
    ("report_top.png", None, "Identified linear model", 2000),
    ("report_diagnosis.png", "Diagnosis", "Evidence", 2000),
    ("report_comparison.png", "What the diagnosis bought", None, 2000),
)


def find_browser(given):
    if given:
        path = shutil.which(given) or (given if os.access(given, os.X_OK) else None)
    else:
        path = next((p for p in map(shutil.which, BROWSERS) if p), None)
    if not path:
        sys.exit(f"make_screenshots: no Chromium/Chrome found ({given or ', '.join(BROWSERS)}); "
                 "install one (apt-get install chromium) or pass --browser PATH")
    return path


def heading_id(page, prefix):
    """The id given to the first <h1>/<h2> whose text starts with prefix."""
    for i, m in enumerate(re.finditer(r"<h[12][^>]*>(.*?)</h[12]>", page, re.S)):
        if html.unescape(re.sub(r"<[^>]+>", "", m.group(1))).strip().startswith(prefix):
            return f"shot-h{i}"
    sys.exit(f"make_screenshots: no heading starting with {prefix!r} in the report")


def section_page(page, report_dir, start, end):
    """The report, with ids on its headings and only the section [start, end) shown."""
    count = iter(range(10**6))
    page = re.sub(r"<h([12])(?=[\s>])", lambda m: f'<h{m.group(1)} id="shot-h{next(count)}"', page)
    css = []
    if start:
        css.append(f"body > :has(~ #{heading_id(page, start)}) {{ display: none }}")
    if end:
        end_id = heading_id(page, end)
        css.append(f"#{end_id}, #{end_id} ~ * {{ display: none }}")
    head = f'<base href="{report_dir.as_uri()}/"><style>{" ".join(css)}</style>'
    return page.replace("</head>", head + "</head>", 1)


def trim_and_shrink(png, max_kb):
    try:
        from PIL import Image, ImageChops
    except ImportError:
        return
    im = Image.open(png).convert("RGB")
    box = ImageChops.difference(im, Image.new("RGB", im.size, "white")).getbbox()
    if box:  # keep the full width, cut the blank space under the content
        im = im.crop((0, 0, im.width, min(im.height, box[3] + 30)))
    im.save(png, optimize=True)
    if png.stat().st_size > max_kb * 1024:
        im.quantize(256, dither=Image.Dither.NONE).save(png, optimize=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--report", required=True, type=Path, help="report.html written by cosim demo")
    ap.add_argument("--out", default=Path("docs/screenshots"), type=Path)
    ap.add_argument("--browser", help="Chromium/Chrome executable (default: looked up on the PATH)")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--max-kb", type=int, default=400, help="larger PNGs are reduced to 256 colours")
    args = ap.parse_args()

    browser = find_browser(args.browser)
    report = args.report.resolve()
    page = report.read_text(encoding="utf-8")
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name, start, end, height in SHOTS:
            copy = Path(tmp) / f"{Path(name).stem}.html"
            copy.write_text(section_page(page, report.parent, start, end), encoding="utf-8")
            png = (args.out / name).resolve()
            png.unlink(missing_ok=True)
            cmd = [browser, "--headless", "--disable-gpu", "--hide-scrollbars",
                   f"--window-size={args.width},{height}", f"--screenshot={png}", copy.as_uri()]
            if hasattr(os, "geteuid") and os.geteuid() == 0:
                cmd.insert(1, "--no-sandbox")
            run = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
            if run.returncode or not png.exists():
                sys.exit(f"make_screenshots: {browser} failed on {name}:\n{run.stderr[-2000:]}")
            trim_and_shrink(png, args.max_kb)
            print(f"{png} ({png.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
