"""Wall time of ``bayeshyst demo --quick`` and ``bayeshyst demo``, per stage.

The README promises the default demo in under 5 minutes and ``--quick`` in under one
on 2 cores. This runs both in fresh subprocesses (numba's cache warm: one untimed quick
run first), reads each run's ``summary.json`` for the per-stage times, and prints the
wall time of the whole command and the ratio default / quick. Run it on an otherwise
idle machine.

Usage::

    python benchmarks/bench_demo.py [--write] [--skip-default]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def run_demo(quick: bool, out: Path) -> tuple[float, dict[str, float]]:
    """Wall time of one ``bayeshyst demo`` subprocess and its per-stage times."""
    cmd = [sys.executable, "-m", "bayeshyst.cli", "demo", "--out", str(out), "--quiet"]
    if quick:
        cmd.append("--quick")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    return wall, json.loads((out / "summary.json").read_text())["runtime_s"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="record in benchmarks/RESULTS.md")
    ap.add_argument("--skip-default", action="store_true", help="time --quick only")
    args = ap.parse_args(argv)
    import numpy as np

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        run_demo(True, Path(tmp) / "warm")  # compile / load numba's cache once
        for quick in (True, False)[: 1 if args.skip_default else 2]:
            wall, stages = run_demo(quick, Path(tmp) / ("quick" if quick else "default"))
            rows.append(("demo --quick" if quick else "demo", wall, stages))
            per = ", ".join(f"{k} {v:.1f} s" for k, v in stages.items())
            print(f"{rows[-1][0]}: {wall:.1f} s ({per})", flush=True)
    lines = [f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}, numpy {np.__version__}; numba cache warm; "
             "measured alone.", "",
             "| command | wall time | compare | diagnose | compensate | ratio |",
             "|---|---|---|---|---|---|"]
    base = rows[0][1]
    for name, wall, st in rows:
        lines.append(f"| `bayeshyst {name}` | {wall:.1f} s | {st.get('compare', 0):.1f} s | "
                     f"{st.get('diagnose', 0):.1f} s | {st.get('compensate', 0):.1f} s | "
                     f"{wall / base:.2f} |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("demo", "The demo (README's first command)", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
