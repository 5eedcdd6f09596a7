"""Wall time of one ``bayeshyst study`` on 1 and 2 Dask workers (and serially, no Dask).

The same study — the bundled virtual actuator's five frequencies × two models × two
seeds, 20 fits — runs three times in fresh subprocesses, each into an empty output
folder: ``--serial`` (the reference: the fits one after the other, no Dask),
``--workers 1`` (Dask's overhead) and ``--workers 2``. Printed: each wall time (cluster
start-up included) and the ratios against the serial run and 1 worker / 2 workers, and
whether the three tables agree (they must: same seeds). Numba's cache is warmed first.
Run it on an otherwise idle machine.

Usage::

    python benchmarks/bench_study.py [--write] [--steps N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

MODELS = ("pi_play(n_operators=5)", "bouc_wen")
SEEDS = (0, 1)


def study_file(folder: Path, steps: int) -> Path:
    """The benchmark's study: the bundled multi-frequency file, every frequency."""
    from bayeshyst.demo import bundled_data

    data = bundled_data("virtual_multifreq.csv", fallback_dir=folder / "data")
    path = folder / "bench.toml"
    path.write_text(textwrap.dedent(f"""\
        name = "bench"
        models = {json.dumps(list(MODELS))}
        seeds = {list(SEEDS)}

        [sampler]
        max_steps = {steps}
        first_chunk = {min(500, steps)}
        max_refits = 0

        [[datasets]]
        path = {json.dumps(str(data))}
        """))
    return path


def run(study: Path, out: Path, how: list[str]) -> float:
    """Wall time of one ``bayeshyst study`` subprocess."""
    cmd = [sys.executable, "-m", "bayeshyst.cli", "study", str(study), "--out", str(out),
           "--quiet", "--no-figures", *how]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _table(out: Path) -> list[dict]:
    rows = json.loads((out / "table.json").read_text())["rows"]
    return [{k: v for k, v in r.items() if k not in ("runtime_s", "worker")} for r in rows]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="record in benchmarks/RESULTS.md")
    ap.add_argument("--steps", type=int, default=600, help="max_steps of every fit")
    args = ap.parse_args(argv)
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        study = study_file(tmp, args.steps)
        run(study, tmp / "warm", ["--serial"])  # compile / load numba's cache once
        times = {}
        for name, how in (("serial (no Dask)", ["--serial"]), ("1 worker", ["--workers", "1"]),
                          ("2 workers", ["--workers", "2"])):
            out = tmp / name.split()[0]
            times[name] = run(study, out, how)
            print(f"{name}: {times[name]:.1f} s", flush=True)
        tables = [_table(tmp / n.split()[0]) for n in times]
        n_fits = len(tables[0])
        same = all(t == tables[0] for t in tables)
    ref, one = times["serial (no Dask)"], times["1 worker"]
    lines = [f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}, numpy {np.__version__}; numba cache warm; "
             "measured alone.", "",
             f"Study: bundled `virtual_multifreq.csv`, 5 frequencies × {len(MODELS)} models "
             f"({', '.join(MODELS)}) × {len(SEEDS)} seeds = {n_fits} fits, max_steps "
             f"{args.steps}; wall time of the whole command (cluster start-up included).", "",
             "| run | wall time | vs serial | speed-up vs 1 worker |", "|---|---|---|---|"]
    for name, t in times.items():
        lines.append(f"| `{name}` | {t:.1f} s | {t / ref:.2f} | {one / t:.2f}x |")
    lines += ["", f"Tables of the three runs identical (same seeds): {'yes' if same else 'NO'}."]
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("study", "A study on Dask: 1 vs 2 workers", text)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
