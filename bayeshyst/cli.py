"""Command line: a thin argparse layer over the public API.

Exit status: 0 success, 2 bad input (one clear line on stderr, nothing written half-way),
1 internal error.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from bayeshyst import __version__
from bayeshyst.errors import DataError, ModelError, ParameterError

__all__ = ["main"]

EXIT_OK, EXIT_INTERNAL, EXIT_BAD_INPUT = 0, 1, 2


def _models_summary(names: Sequence[str]) -> list[dict[str, Any]]:
    from bayeshyst import models

    out = []
    for name in names:
        model = models.get(name)
        space = model.param_space()
        params = []
        for p in space.params:
            params.append({"name": p.name, "shape": list(p.shape), "unit": p.unit,
                           "prior": str(p.prior), "description": p.description})
        for p in space.fixed_params:
            params.append({"name": p.name, "shape": list(p.shape), "unit": p.unit,
                           "fixed": np.asarray(space.fixed[p.name]).tolist(),
                           "description": p.description})
        out.append({
            "name": name,
            "class": type(model).__name__,
            "equation": model.equation,
            "rate_dependent": bool(model.rate_dependent),
            "analytic_inverse": bool(model.has_inverse),
            "summary": (type(model).__doc__ or "").strip().splitlines()[0],
            "settings": {k: v for k, v in vars(model).items() if not k.startswith("_")},
            "parameters": params,
        })
    return out


def _cmd_models(args: argparse.Namespace) -> int:
    from bayeshyst import models

    names = models.names()
    if args.name:
        unknown = [n for n in args.name if n not in names]
        if unknown:
            raise ModelError(f"unknown model(s) {unknown}; available: {', '.join(names)}")
        names = args.name
    summary = _models_summary(names)
    if args.json:
        json.dump({"models": summary}, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
        return EXIT_OK
    for m in summary:
        flags = []
        if m["rate_dependent"]:
            flags.append("rate-dependent")
        if m["analytic_inverse"]:
            flags.append("analytic inverse")
        settings = ", ".join(f"{k}={v}" for k, v in m["settings"].items())
        print(f"{m['name']}  [{m['class']}({settings})]  {m['equation']}"
              + (f"  ({'; '.join(flags)})" if flags else ""))
        print(f"    {m['summary']}")
        for p in m["parameters"]:
            shape = "x".join(map(str, p["shape"])) or "scalar"
            what = p.get("prior") or f"fixed = {np.round(p['fixed'], 4).tolist()}"
            print(f"    {p['name']:<16} {shape:<7} {p['unit']:<8} {what}  - {p['description']}")
        print()
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``bayeshyst`` command."""
    # argparse itself exits with status 2 on usage errors, as bad input should
    parser = argparse.ArgumentParser(prog="bayeshyst",
                     description="Bayesian identification of hysteresis in piezo actuators.")
    parser.add_argument("--version", action="version", version=f"bayeshyst {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p_models = sub.add_parser("models", help="list the models, their parameters and priors")
    p_models.add_argument("name", nargs="*", help="only these models")
    p_models.add_argument("--json", action="store_true", help="print JSON to stdout")
    p_models.set_defaults(func=_cmd_models)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (DataError, ParameterError, ModelError) as exc:
        print(f"bayeshyst {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        # the reader went away (``bayeshyst models | head``): not an error; point stdout
        # at devnull so the interpreter's final flush does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except KeyboardInterrupt:
        print(f"bayeshyst {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
