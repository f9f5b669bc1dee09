"""Screenshots of the demo's tabs on a loaded machine: how many succeed, how long each takes.

    python tools/screenshot_load.py [--rrd demo.rrd] [--shots 10] [--busy 2] [--wait-s 90] [--tab NAME ...]
                                    [--keep DIR]

Starts --busy CPU-bound loops (python -c 'while 1: pass'; ended when done), then takes --shots
screenshots through the CLI as a user would (`accellog view RRD --screenshot PNG --tab TAB
--wait-s W`), cycling through the tabs (the demo's four, or each --tab given; '-' for the recording's
own first view), one after the other. For each: exit code, wall time, the
1-minute load average at its start, and whether a failed run left a PNG behind (it must not).
Without --rrd the demo's recording is made first (`accellog demo --quick`). --keep DIR: the PNGs
are kept there (shotK_TAB.png), to be looked at.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TABS = ("1 calibration session", "2 static test", "3 workbench", "4 moving robot")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rrd", type=Path, help="the demo's recording (default: make one)")
    ap.add_argument("--shots", type=int, default=10)
    ap.add_argument("--busy", type=int, default=2, help="CPU-bound loops running meanwhile")
    ap.add_argument("--wait-s", type=float, default=90.0, help="view --wait-s")
    ap.add_argument("--tab", action="append", help="a tab to screenshot (repeatable; '-': none given)")
    ap.add_argument("--keep", type=Path, help="keep the screenshots in this folder")
    a = ap.parse_args()
    tabs = tuple(a.tab) if a.tab else TABS
    cli = [sys.executable, "-m", "accellog"]
    with tempfile.TemporaryDirectory(prefix="accellog-shots-") as d:
        rrd = a.rrd
        if rrd is None:
            rrd = Path(d) / "demo.rrd"
            subprocess.run(
                [*cli, "demo", "--quick", "-o", f"{d}/demo", "--rrd", str(rrd)],
                check=True,
                stdout=subprocess.DEVNULL,
            )
        busy = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(a.busy)]
        ok = 0
        try:
            for k in range(a.shots):
                tab, png = tabs[k % len(tabs)], Path(d) / f"shot{k}.png"
                load = os.getloadavg()[0]
                t0 = time.monotonic()
                p = subprocess.run(
                    [
                        *cli,
                        "view",
                        str(rrd),
                        "--screenshot",
                        str(png),
                        *(["--tab", tab] if tab != "-" else []),
                        "--wait-s",
                        f"{a.wait_s:g}",
                    ],
                    capture_output=True,
                    text=True,
                )
                wall = time.monotonic() - t0
                ok += p.returncode == 0
                if a.keep is not None and p.returncode == 0:
                    a.keep.mkdir(parents=True, exist_ok=True)
                    name = "".join(c if c.isalnum() else "_" for c in tab)[:40]
                    png.replace(a.keep / f"shot{k}_{name}.png")
                left = "" if p.returncode == 0 else f"  PNG left: {png.exists()}  {p.stderr.strip()[-160:]}"
                print(
                    f"{k + 1:2d} {tab[:22]:22s} exit {p.returncode}  {wall:6.1f} s  load {load:5.2f}{left}",
                    flush=True,
                )
        finally:
            for b in busy:
                b.kill()
                b.wait()
    print(f"{ok}/{a.shots} screenshots succeeded with {a.busy} busy loops (--wait-s {a.wait_s:g})")
    return 0 if ok == a.shots else 1


if __name__ == "__main__":
    raise SystemExit(main())
