"""Command line: a thin argparse layer over the public API.

Exit status: 0 success, 2 bad input (one clear line on stderr, nothing written half-way),
1 internal error. The commands are in :mod:`bayeshyst.cli.commands` (those of the whole
study, `report`, `demo` and `study`, in :mod:`bayeshyst.cli.study_commands`), the parser in
:mod:`bayeshyst.cli.parser`, the option types and the one mapping of options onto
:class:`~bayeshyst.inference.settings.SamplerSettings` in :mod:`bayeshyst.cli.options`.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence

from bayeshyst.cli.options import (
    EXIT_BAD_INPUT,
    EXIT_OK,
    int_at_least,
    non_negative_float,
    non_negative_int,
    positive_int,
    probability,
    sampler_settings,
)
from bayeshyst.cli.parser import build_parser
from bayeshyst.errors import DataError, ModelError, ParameterError

__all__ = ["build_parser", "int_at_least", "main", "non_negative_float", "non_negative_int",
           "positive_int", "probability", "sampler_settings"]


def _log_to_stderr(level: int) -> None:
    """Show the library's log records (logger ``bayeshyst``) on stderr at ``level``.

    Only bayeshyst's own: third-party debug logs (numba, matplotlib) stay silent. One
    handler, however often ``main`` runs in a process.
    """
    logger = logging.getLogger("bayeshyst")
    logger.setLevel(level)
    if not any(getattr(h, "_bayeshyst", False) for h in logger.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
        handler._bayeshyst = True  # type: ignore[attr-defined]
        logger.addHandler(handler)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "verbose", 0):
        _log_to_stderr(logging.DEBUG if args.verbose > 1 else logging.INFO)
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
