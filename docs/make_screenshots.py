"""Screenshots of cosim's HTML reports for the README (docs/screenshots/*.png).

Run from the repository root. With ``--run DIR`` it first writes every kind of report with the real commands
(``cosim demo``, ``cosim simulate`` + ``cosim diagnose --report``, ``cosim validate --report`` on the demo's
MPC, ``cosim reproduce paper``) into DIR, then takes the screenshots::

    python docs/make_screenshots.py --run /tmp/shots --out docs/screenshots

or takes them of reports already written (any subset)::

    cosim demo --out-dir /tmp/demo
    python docs/make_screenshots.py --demo /tmp/demo/report.html --out docs/screenshots

Each report's top (the title and its summary box) is one shot (``report_top.png``, ``diagnosis_top.png``,
``validation_top.png``, ``reproduce_top.png``); the demo's diagnosis and its controllers compared are two
more (``report_diagnosis.png``, ``report_comparison.png``).

It needs a Chromium or Google Chrome binary (headless mode, version 112 or later); on
Debian/Ubuntu ``apt-get install chromium``.  It is looked up on the PATH (chromium,
chromium-browser, google-chrome, ...) unless given with ``--browser PATH``.  Pillow
(installed with matplotlib) trims the blank space under each section.  Neither is a
dependency of cosim.

The reports have no element ids, so each section is found by its heading text: a copy of the
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
#: Ends a shot at the report's first section heading (the top: the title and the summary box).
FIRST_SECTION = object()

# report kind -> (file name, first heading (text prefix; None = top of the page), heading that ends the
# section (None = end of the page; FIRST_SECTION = the first <h2>), window height in px)
SHOTS = {
    "demo": (("report_top.png", None, FIRST_SECTION, 1400),
             ("report_diagnosis.png", "Diagnosis", "Evidence", 2000),
             ("report_comparison.png", "What the diagnosis bought", None, 2000)),
    "diagnosis": (("diagnosis_top.png", None, FIRST_SECTION, 1400),),
    "validation": (("validation_top.png", None, FIRST_SECTION, 1400),),
    "reproduce": (("reproduce_top.png", None, FIRST_SECTION, 1400),),
}
STATES = "theta_m,omega_m,theta_L,omega_L"


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
    """The id given to the first <h1>/<h2> whose text starts with prefix (FIRST_SECTION: the first <h2>)."""
    for i, m in enumerate(re.finditer(r"<h([12])[^>]*>(.*?)</h[12]>", page, re.S)):
        if prefix is FIRST_SECTION:
            if m.group(1) == "2":
                return f"shot-h{i}"
            continue
        if html.unescape(re.sub(r"<[^>]+>", "", m.group(2))).strip().startswith(prefix):
            return f"shot-h{i}"
    if prefix is FIRST_SECTION:
        return None
    sys.exit(f"make_screenshots: no heading starting with {prefix!r} in the report")


def section_page(page, report_dir, start, end):
    """The report, with ids on its headings and only the section [start, end) shown."""
    count = iter(range(10**6))
    page = re.sub(r"<h([12])(?=[\s>])", lambda m: f'<h{m.group(1)} id="shot-h{next(count)}"', page)
    css = []
    if start:
        css.append(f"body > :has(~ #{heading_id(page, start)}) {{ display: none }}")
    end_id = heading_id(page, end) if end else None
    if end_id:
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


def cosim(*args, ok=(0,)):
    """Run ``cosim ARGS`` (the command of this environment); stop on an exit status not in `ok`."""
    exe = shutil.which("cosim") or sys.exit("make_screenshots: no `cosim` command on the PATH (pip install -e .)")
    print("$ cosim " + " ".join(args), flush=True)
    run = subprocess.run([exe, *args], capture_output=True, text=True)
    if run.returncode not in ok:
        sys.exit(f"make_screenshots: cosim {args[0]} exited {run.returncode}:\n{run.stderr[-2000:]}")


def write_reports(folder):
    """Every kind of report, written by the real commands into `folder`; {kind: report path}."""
    folder = folder.resolve()
    demo, diag, val, repro = (folder / name for name in ("demo", "diagnose", "validate", "reproduce"))
    cosim("demo", "--out-dir", str(demo), "--no-progress")
    diag.mkdir(parents=True, exist_ok=True)
    cosim("simulate", "bundled", "--input", "Tm=multisine:amp=1000,fmin=1,fmax=40", "--duration", "2", "--dt",
          "1/2257", "--set", "Fc=100", "--noise", "0.05", "--seed", "1", "-o", str(diag / "data.csv"))
    cosim("diagnose", str(diag / "data.csv"), "--state", STATES, "--input", "Tm", "--report",
          str(diag / "diagnosis.html"))
    val.mkdir(parents=True, exist_ok=True)
    cosim("validate", "bundled", str(demo / "mpc.json"), "--scenario", "step:amp=0.01,duration=2", "--scenario",
          "disturbance:amp=500,at=0.5", "--set", "Fc=100", "--robustness", "8", "--spread", "0.2", "--effect",
          "Fc=0:200", "--no-progress", "--report", str(val / "validation.html"), ok=(0, 1))
    cosim("reproduce", "paper", "--seeds", "1", "--out-dir", str(repro), "--no-progress")
    return {"demo": demo / "report.html", "diagnosis": diag / "diagnosis.html",
            "validation": val / "validation.html", "reproduce": repro / "report.html"}


def shoot(browser, report, shots, out, width, max_kb):
    """Take `shots` of `report` into `out`, each with a fresh, empty browser profile."""
    report = report.resolve()
    page = report.read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory() as tmp:
        for name, start, end, height in shots:
            copy = Path(tmp) / f"{Path(name).stem}.html"
            copy.write_text(section_page(page, report.parent, start, end), encoding="utf-8")
            png = (out / name).resolve()
            png.unlink(missing_ok=True)
            profile = Path(tmp) / f"profile-{Path(name).stem}"
            profile.mkdir()
            cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                   "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}",
                   "--hide-scrollbars", f"--window-size={width},{height}", f"--screenshot={png}", copy.as_uri()]
            run = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
            if run.returncode or not png.exists():
                sys.exit(f"make_screenshots: {browser} failed on {name}:\n{run.stderr[-2000:]}")
            trim_and_shrink(png, max_kb)
            print(f"{png} ({png.stat().st_size // 1024} KB)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, metavar="DIR",
                    help="first write every kind of report into DIR with the real commands, then shoot them all")
    ap.add_argument("--demo", "--report", dest="demo", type=Path, help="report.html written by cosim demo")
    ap.add_argument("--diagnosis", type=Path, help="the HTML of cosim diagnose --report")
    ap.add_argument("--validation", type=Path, help="the HTML of cosim validate --report")
    ap.add_argument("--reproduce", type=Path, help="report.html written by cosim reproduce paper")
    ap.add_argument("--out", default=Path("docs/screenshots"), type=Path)
    ap.add_argument("--browser", help="Chromium/Chrome executable (default: looked up on the PATH)")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--max-kb", type=int, default=400, help="larger PNGs are reduced to 256 colours")
    args = ap.parse_args()

    browser = find_browser(args.browser)
    reports = write_reports(args.run) if args.run else {
        kind: getattr(args, kind) for kind in SHOTS if getattr(args, kind) is not None}
    if not reports:
        ap.error("give --run DIR, or at least one of --demo, --diagnosis, --validation, --reproduce")
    args.out.mkdir(parents=True, exist_ok=True)
    for kind, report in reports.items():
        shoot(browser, report, SHOTS[kind], args.out, args.width, args.max_kb)


if __name__ == "__main__":
    main()
