"""Atomic file writing: every output appears whole or not at all.

A writer gets temporary paths in the destination folders (same file system, so the
final ``os.replace`` is atomic); only when every one of them has been written are they
renamed into place, and on any exception they are removed. The results get the
permissions a plain ``open()`` would have given them (``mkstemp`` makes 0600 files), or
keep those of the file they replace.

The same holds for a whole run: :func:`removed_on_failure` takes back what a command
created in its output folder (checkpoints, half a set of outputs, the folder itself)
when it fails before its first result, and nothing that was there before.

JSON goes through one serialiser, :func:`json_text` (plain types, no NaN): what
:func:`write_json` puts in a file and what a command prints for ``--json`` are the
same text.

This module is at the bottom of the package: data writers, figures, netCDF posteriors
and JSON summaries all use it.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["RunOutputs", "atomic_path", "atomic_paths", "json_text", "jsonable",
           "removed_on_failure", "write_json"]


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


def jsonable(obj: Any) -> Any:
    """``obj`` with NumPy types made plain and non-finite floats made ``None``.

    JSON has no NaN or infinity; writing them would make files that strict parsers
    reject, so a missing number is ``null``.

    Parameters
    ----------
    obj : any
        Nested dicts, lists, tuples, arrays and scalars.

    Returns
    -------
    any
        The same structure of plain Python types (dict keys as ``str``, tuples and
        arrays as lists); objects of other types are returned as they are.
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        x = float(obj)
        return x if math.isfinite(x) else None
    return obj


def json_text(obj: Any, *, default: Callable[[Any], Any] = str) -> str:
    """``obj`` as indented JSON text with a final newline.

    The one serialiser of the package's JSON files (:func:`write_json`) and of what
    ``--json`` prints.

    Parameters
    ----------
    obj : any
        Made plain by :func:`jsonable` first (non-finite numbers become ``null``).
    default : callable
        Turns what JSON cannot hold (a path, a model object) into something it can.

    Returns
    -------
    str
    """
    return json.dumps(jsonable(obj), indent=2, default=default, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike[str], obj: Any, *,
               default: Callable[[Any], Any] = str) -> Path:
    """Write ``obj`` as :func:`json_text` atomically.

    Parameters
    ----------
    path : path-like
        Target file (its folder is created if needed).
    obj : any
        What to write.
    default : callable
        As in :func:`json_text`.

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(json_text(obj, default=default))
    return Path(path)


def _tree(root: Path) -> set[Path]:
    """Every path below ``root`` (files, folders, links; links are not followed)."""
    found: set[Path] = set()
    if not root.is_dir():
        return found
    for folder, dirs, files in os.walk(root):
        base = Path(folder)
        found.update(base / name for name in (*dirs, *files))
    return found


class RunOutputs:
    """What a run found in its output folder, and whether it has a result yet.

    Made by :func:`removed_on_failure`; a command calls :meth:`keep` once it has its
    first result.
    """

    def __init__(self, folder: str | os.PathLike[str],
                 results: Sequence[str] = ()) -> None:
        self.folder = Path(folder)
        self.results = tuple(results)
        self.kept = False
        # the folder and the parents a mkdir(parents=True) would create, deepest first
        self._missing = [p for p in (self.folder, *self.folder.parents) if not p.exists()]
        self._before = _tree(self.folder)

    def keep(self) -> None:
        """Mark the run as having a result: a later failure removes nothing."""
        self.kept = True

    def created(self) -> list[Path]:
        """Paths below the folder that were not there when the run started."""
        return sorted(_tree(self.folder) - self._before)

    def has_result(self) -> bool:
        """Whether :meth:`keep` was called, or a created path matches ``results``."""
        if self.kept:
            return True
        if not self.results:
            return False
        # paths relative to the folder, matched like Path.match (e.g. "fits/*.json")
        return any(p.relative_to(self.folder).match(pattern)
                   for p in self.created() for pattern in self.results)

    def remove_created(self) -> None:
        """Remove what the run created (never what was there before), then the folder.

        The folder and its parents are removed only if the run created them and they are
        empty.
        """
        # files and links first, then folders deepest first; rmdir, not rmtree: a
        # folder that is not empty holds something this run did not make
        created = self.created()
        for path in created:
            if path.is_symlink() or not path.is_dir():
                with suppress(FileNotFoundError):
                    path.unlink()
        for path in sorted((p for p in created if p.is_dir() and not p.is_symlink()),
                           key=lambda p: len(p.parts), reverse=True):
            with suppress(OSError):
                path.rmdir()
        for path in self._missing:
            with suppress(OSError):
                path.rmdir()


@contextmanager
def removed_on_failure(folder: str | os.PathLike[str], *,
                       results: Sequence[str] = ()) -> Iterator[RunOutputs]:
    """Remove what the block creates under ``folder`` if it fails before a result.

    A command that fails (any exception) before its first result leaves the folder as
    it found it: checkpoints and outputs it created are removed, the folder too if it
    did not exist; files that were there before (a user's, or the checkpoint of an
    earlier run being resumed) are never touched. Once the run has a result — the
    command called :meth:`RunOutputs.keep`, or it created a path matching one of
    ``results`` — a failure removes nothing, so a rerun resumes from what is there.
    ``KeyboardInterrupt`` removes nothing either: an interrupted run is resumed, not
    failed.

    Parameters
    ----------
    folder : path-like
        The command's output folder (need not exist).
    results : sequence of str
        Glob patterns, relative to ``folder``, of files that are results (e.g.
        ``"fits/*.json"`` for runs that store each result as it completes).

    Yields
    ------
    RunOutputs
        Call its ``keep()`` once the run has its first result.

    Notes
    -----
    Meant for one command writing into its own folder: a file another process creates
    there during the run would be taken for the run's own.
    """
    outputs = RunOutputs(folder, results)
    try:
        yield outputs
    except Exception:
        if not outputs.has_result():
            outputs.remove_created()
        raise
