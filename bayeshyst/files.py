"""Atomic file writing: every output appears whole or not at all.

A writer gets temporary paths in the destination folders (same file system, so the
final ``os.replace`` is atomic); only when every one of them has been written are they
renamed into place, and on any exception they are removed. The results get the
permissions a plain ``open()`` would have given them (``mkstemp`` makes 0600 files), or
keep those of the file they replace.

This module is at the bottom of the package: data writers, figures, netCDF posteriors
and JSON summaries all use it.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_path", "atomic_paths"]


def _default_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextmanager
def atomic_paths(targets: Sequence[str | os.PathLike[str]]) -> Iterator[list[Path]]:
    """Yield one temporary path per target; rename them all into place on success.

    Parameters
    ----------
    targets : sequence of path-like
        Final paths; their folders are created if needed.

    Yields
    ------
    list of Path
        Temporary paths, in the order of ``targets``, to be written by the caller.
    """
    temps: list[tuple[Path, Path]] = []
    try:
        for target in map(Path, targets):
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                                       dir=target.parent)
            os.close(fd)
            mode = target.stat().st_mode & 0o777 if target.exists() else _default_mode()
            os.chmod(tmp, mode)
            temps.append((Path(tmp), target))
        yield [tmp for tmp, _ in temps]
        for tmp, target in temps:
            os.replace(tmp, target)
    finally:
        for tmp, _ in temps:
            tmp.unlink(missing_ok=True)


@contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; rename it to ``target`` on success."""
    with atomic_paths([target]) as (tmp,):
        yield tmp
