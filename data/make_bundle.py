"""Regenerate the virtual-actuator datasets in this folder, bit for bit.

Usage (from the repository root)::

    python data/make_bundle.py                  # writes into data/, seed 20240611
    python data/make_bundle.py --out DIR --seed N

The files are described in ``data/README.md``; the simulator is
:class:`bayeshyst.data.virtual.VirtualActuator` and the recipe
:func:`bayeshyst.data.virtual.bundle`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
# run from a checkout without installing: the package next to this folder wins
sys.path.insert(0, str(HERE.parent))

from bayeshyst.data.virtual import BUNDLE_SEED, bundle  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Write the bundle; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE, help="output folder (default: data/)")
    parser.add_argument("--seed", type=int, default=BUNDLE_SEED,
                        help=f"root seed (default: {BUNDLE_SEED})")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for path in bundle(args.out, seed=args.seed):
        print(f"wrote {path} ({path.stat().st_size} bytes) and its .json sidecar")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
