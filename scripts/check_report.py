#!/usr/bin/env python3
"""Look at a bcbench HTML report as a reader would: in headless Chromium, at a laptop's and a phone's size.

    python scripts/check_report.py results/cpu/report/report.html [--out DIR]

Checks, at 1280 x 900 (a laptop's first screen): the "Which policy for my control loop" table ends inside the
first screen (the report opens with Figure 5 and that table), nothing is wider than the window (no sideways
scrolling), and every figure decoded. Prints the measurements as JSON, writes screenshots at 1280 x 900 and
390 x 844 into --out when given, and exits 1 when a check fails, 2 when there is no Chromium.

Needs Chromium (Debian: `apt-get install chromium`; or name one in $CHROMIUM). Stdlib only.
"""

from __future__ import annotations

import argparse
import html
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

# flags a closed network needs (no background connections, no update checks), as root in a container
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars"]
PROBE = """<script>addEventListener('load', () => {
  const tables = [...document.querySelectorAll('table')];
  const choose = tables.length ? tables[0].getBoundingClientRect() : null;
  document.body.setAttribute('data-layout', JSON.stringify({
    choose_table_bottom: choose && choose.bottom + scrollY, scroll_width: document.documentElement.scrollWidth,
    window_width: innerWidth, window_height: innerHeight,
    figures: [...document.images].map(i => i.complete && i.naturalWidth > 0)}));
});</script>"""


def chromium() -> str | None:
    return os.environ.get("CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


def _run(exe: str, size: tuple[int, int], *args: str) -> str:
    with tempfile.TemporaryDirectory(prefix="bcbench-chromium-") as profile:
        cmd = [exe, *FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}", *args]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True).stdout


def layout(exe: str, report: Path, size: tuple[int, int] = (1280, 900)) -> dict:
    """Measurements of `report` laid out at `size` (the page with a probe script added, DOM dumped)."""
    with tempfile.TemporaryDirectory(prefix="bcbench-layout-") as tmp:
        probed = Path(tmp) / "report.html"
        probed.write_text(report.read_text().replace("</body>", PROBE + "</body>"))
        dom = _run(exe, size, "--virtual-time-budget=10000", "--dump-dom", probed.as_uri())
    found = re.search(r'data-layout="([^"]*)"', dom)
    if not found:
        raise RuntimeError("the page did not finish loading in Chromium")
    return json.loads(html.unescape(found.group(1)))


def problems(m: dict) -> list[str]:
    out = []
    if m["choose_table_bottom"] is None:
        out.append("no 'Which policy for my control loop' table")
    elif m["choose_table_bottom"] > m["window_height"]:
        out.append(f"the choice table ends at {m['choose_table_bottom']:.0f} px, below the first screen "
                   f"({m['window_height']} px)")
    if m["scroll_width"] > m["window_width"]:
        out.append(f"the page is {m['scroll_width']} px wide in a {m['window_width']} px window (sideways scrolling)")
    if not all(m["figures"]):
        out.append(f"{m['figures'].count(False)} figure(s) did not decode")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path, help="a report.html written by `bcbench report`")
    ap.add_argument("--out", type=Path, help="write screenshots here (laptop-1280x900.png, phone-390x844.png)")
    args = ap.parse_args()
    exe = chromium()
    if exe is None:
        print("check_report: no Chromium (apt-get install chromium, or set $CHROMIUM)", file=sys.stderr)
        return 2
    if not args.report.is_file():
        print(f"check_report: {args.report}: no such file", file=sys.stderr)
        return 2
    m = layout(exe, args.report.resolve())
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        for name, size in (("laptop", (1280, 900)), ("phone", (390, 844))):
            _run(exe, size, f"--screenshot={(args.out / f'{name}-{size[0]}x{size[1]}.png').resolve()}",
                 args.report.resolve().as_uri())
    found = problems(m)
    print(json.dumps({**m, "problems": found}))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
