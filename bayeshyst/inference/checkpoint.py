"""Checkpointing of emcee ensembles to HDF5, safe against being killed at any instant.

:class:`CheckpointBackend` is emcee's ``HDFBackend`` with two changes:

* steps are buffered in memory and written every ``flush_seconds`` (and whenever the
  sampler asks for the chain), instead of opening the file on every step;
* a flush writes the new rows first and then *one* attribute, ``checkpoint``, holding
  the iteration count, the random state and the acceptance counts together. On open,
  that attribute is the truth: rows beyond it (a flush cut short by a kill) are
  ignored and emcee's own ``iteration`` attribute is repaired to match.

Because the random state is stored with the step it belongs to, a run resumed from a
checkpoint continues exactly as the uninterrupted run would have: the steps lost with
the in-memory buffer are recomputed identically, none is duplicated.

The run's identity (model, data, likelihood, priors, sampler settings) is stored as a
fingerprint; resuming a file written for a different run is refused.

Nothing here unpickles. A checkpoint is JSON and arrays only (format
:data:`CHECKPOINT_FORMAT`): the random state is stored as its numbers, the run's
metadata as JSON whose arrays are tagged with a numeric dtype. A file someone sent
you is data, never code; files of the older, pickled format are refused with the
reason, not opened.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from emcee.backends import HDFBackend

from bayeshyst.errors import ParameterError

_log = logging.getLogger(__name__)
#: Longest wait (s) for another process's lock on a checkpoint file before giving up.
LOCK_WAIT_S = 60.0

__all__ = ["CHECKPOINT_FORMAT", "CheckpointBackend", "check_fingerprint", "read_meta",
           "write_meta"]

#: version of the on-disk layout (2: JSON and arrays; 1, pickled attributes, is refused)
CHECKPOINT_FORMAT = 2
#: file attribute holding the format; dataset holding the run's metadata (JSON text);
#: group attribute holding each ensemble's last flushed step (JSON text)
_FORMAT_ATTR, _META, _STEP = "bayeshyst_format", "bayeshyst_run", "checkpoint_json"
#: what the pickled format 1 stored: their presence names an old (or crafted) file
_PICKLED = ("bayeshyst_meta", "checkpoint")
#: numpy dtypes an array in the metadata may have (no object arrays, nothing to import)
_ARRAY_KINDS = "biuf"


def _refuse_pickled(path: Any, where: str) -> None:
    raise ParameterError(
        f"checkpoint {path}: {where} holds a pickled attribute (the format of bayeshyst "
        "before checkpoint format 2, or a crafted file). It is not opened: unpickling runs "
        "code from the file. Delete the checkpoint to start afresh")


def _encode(obj: Any) -> Any:
    """JSON-ready form of the metadata: arrays tagged with their dtype and shape."""
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in _ARRAY_KINDS:
            raise ParameterError(f"checkpoint metadata: arrays of dtype {obj.dtype} are not "
                                 "stored (numbers and booleans only)")
        return {"__ndarray__": {"dtype": obj.dtype.str, "shape": list(obj.shape),
                                "data": obj.ravel().tolist()}}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {str(k): _encode(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_encode(v) for v in obj]
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise ParameterError(f"checkpoint metadata: cannot store a {type(obj).__name__}")


def _decode_array(d: dict[str, Any]) -> dict[str, Any] | np.ndarray:
    spec = d.get("__ndarray__")
    if not isinstance(spec, dict):
        return d
    dtype = np.dtype(str(spec.get("dtype")))
    if dtype.kind not in _ARRAY_KINDS:
        raise ParameterError(f"checkpoint metadata: array of dtype {dtype} refused")
    return np.asarray(spec.get("data"), dtype=dtype).reshape(tuple(spec.get("shape")))


def _loads(text: Any, path: Any, where: str) -> Any:
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    try:
        return json.loads(str(text), object_hook=_decode_array)
    except (ValueError, TypeError) as exc:
        raise ParameterError(f"checkpoint {path}: {where} is not valid checkpoint JSON "
                             f"({exc}); delete it to start afresh") from exc


def _encode_random_state(state: Any) -> dict[str, Any] | None:
    """The legacy MT19937 state tuple of numpy (what emcee keeps) as numbers."""
    if state is None:
        return None
    kind, key, pos, has_gauss, cached = state
    return {"kind": str(kind), "key": np.asarray(key, dtype=np.uint32).tolist(),
            "pos": int(pos), "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}


def _decode_random_state(d: Any, path: Any) -> tuple | None:
    if d is None:
        return None
    try:
        key = np.asarray(d["key"], dtype=np.uint32)
        state = (str(d["kind"]), key, int(d["pos"]), int(d["has_gauss"]),
                 float(d["cached_gaussian"]))
        np.random.RandomState().set_state(state)  # validates kind, key length and pos
    except (KeyError, TypeError, ValueError, OverflowError) as exc:
        raise ParameterError(f"checkpoint {path}: the stored random state is not a "
                             f"MT19937 state ({exc}); delete it to start afresh") from exc
    return state


class CheckpointBackend(HDFBackend):
    """emcee HDF5 backend with buffered, kill-safe flushes (see module docstring).

    Parameters
    ----------
    filename : str or Path
        HDF5 file (shared by the ensembles of one run, one group each).
    name : str
        Group name of this ensemble.
    flush_seconds : float
        Longest time buffered steps stay in memory.
    """

    def __init__(self, filename: str | Path, name: str, *, flush_seconds: float = 2.0) -> None:
        super().__init__(str(filename), name=name)
        self.flush_seconds = float(flush_seconds)
        self._coords: list[np.ndarray] = []
        self._log_prob: list[np.ndarray] = []
        self._accepted: np.ndarray | None = None
        self._random_state: Any = None
        self._last_flush = time.monotonic()
        self._shape: tuple[int, int] | None = None
        #: called at every flush; its JSON-ready dict is stored with the step count it
        #: belongs to (the moves' acceptance counts), see :meth:`stored_extra`
        self.extra_provider: Callable[[], dict[str, Any]] | None = None
        if self.initialized:
            self._repair()

    # ------------------------------------------------------------------ on disk
    def _read_checkpoint(self, g: h5py.Group) -> dict[str, Any] | None:
        if _PICKLED[1] in g.attrs:
            _refuse_pickled(self.filename, f"group {self.name!r}")
        raw = g.attrs.get(_STEP)
        if raw is None:
            return None
        ck = _loads(raw, self.filename, f"group {self.name!r}")
        if not isinstance(ck, dict) or "iteration" not in ck:
            raise ParameterError(f"checkpoint {self.filename}: group {self.name!r} has no "
                                 "step record; delete it to start afresh")
        ck["accepted"] = np.asarray(ck.get("accepted", []), dtype=int)
        ck["random_state"] = _decode_random_state(ck.get("random_state"), self.filename)
        return ck

    @staticmethod
    def _step_record(iteration: int, random_state: Any, accepted: np.ndarray,
                     extra: dict[str, Any] | None) -> str:
        return json.dumps({"iteration": int(iteration),
                           "random_state": _encode_random_state(random_state),
                           "accepted": np.asarray(accepted, dtype=int).tolist(),
                           "extra": _encode(extra)})

    def _repair(self) -> None:
        # read first: a finished run opened by a second reader (another command reusing
        # the fit) must not be written to
        with self.open("r") as f:
            g = f[self.name]
            ck = self._read_checkpoint(g)
            consistent = (ck is not None and int(g.attrs["iteration"]) == ck["iteration"]
                          and np.array_equal(g["accepted"][...], ck["accepted"]))
        if consistent:
            return
        with self.open("a") as f:
            g = f[self.name]
            if ck is None:
                g.attrs["iteration"] = 0
                g["accepted"][:] = 0
                return
            if int(g.attrs["iteration"]) != ck["iteration"]:
                g.attrs["iteration"] = ck["iteration"]
            g["accepted"][:] = ck["accepted"]

    def reset(self, nwalkers: int, ndim: int) -> None:
        """Clear the ensemble's group for a new run and store an empty checkpoint.

        The buffers are emptied, the acceptance counts zeroed and the ``checkpoint``
        attribute set to iteration 0 without a random state.

        Parameters
        ----------
        nwalkers : int
            Walkers of the ensemble.
        ndim : int
            Dimension of each walker's coordinates.
        """
        super().reset(nwalkers, ndim)
        self._coords, self._log_prob = [], []
        self._accepted = np.zeros(nwalkers, dtype=int)
        with self.open("a") as f:
            g = f[self.name]
            g.attrs[_STEP] = self._step_record(0, None, np.zeros(nwalkers, int), None)

    @property
    def random_state(self) -> Any:
        """Random state of the last step: the buffered one, else the stored checkpoint's."""
        if self._random_state is not None:
            return self._random_state
        if not self.initialized:
            return None
        with self.open() as f:
            ck = self._read_checkpoint(f[self.name])
        return None if ck is None else ck["random_state"]

    def stored_extra(self) -> dict[str, Any] | None:
        """The extra state stored with the last flushed step (None if none)."""
        if not self.initialized:
            return None
        with self.open() as f:
            ck = self._read_checkpoint(f[self.name])
        return None if ck is None else ck.get("extra")

    @property
    def iteration(self) -> int:
        """Steps taken: those on disk plus the buffered ones."""
        return super().iteration + len(self._coords)

    # ------------------------------------------------------------------ buffering
    def grow(self, ngrow: int, blobs: Any) -> None:
        """Flush the buffer, then enlarge the datasets by ``ngrow`` steps (emcee's ``grow``).

        Parameters
        ----------
        ngrow : int
            Number of steps to make room for.
        blobs : Any
            Passed on to emcee; :meth:`save_step` refuses steps that carry blobs.
        """
        self.flush()
        super().grow(ngrow, blobs)

    def save_step(self, state: Any, accepted: np.ndarray) -> None:
        """Buffer one step; flush once ``flush_seconds`` have passed since the last flush.

        Parameters
        ----------
        state : emcee.State
            The step's coordinates (W, ndim), log posteriors (W,) and random state.
        accepted : ndarray of bool, shape (W,)
            Walkers whose proposal was accepted at this step.

        Raises
        ------
        ParameterError
            If the state carries blobs or its shape does not fit the checkpoint.
        """
        if state.blobs is not None:
            raise ParameterError("the checkpoint backend does not store blobs")
        # emcee's _check opens the file twice per step; check against the cached shape
        if self._shape is None:
            self._shape = self.shape
        if state.coords.shape != self._shape or np.shape(accepted) != self._shape[:1]:
            raise ParameterError(f"step of shape {state.coords.shape} does not fit the "
                                 f"checkpoint's {self._shape}")
        if self._accepted is None:
            with self.open() as f:
                self._accepted = np.array(f[self.name]["accepted"][...], dtype=int)
        self._coords.append(np.array(state.coords, dtype=float))
        self._log_prob.append(np.array(state.log_prob, dtype=float))
        self._accepted = self._accepted + np.asarray(accepted, dtype=int)
        self._random_state = state.random_state
        if time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def open(self, mode: str = "r") -> Any:
        """Open the file as emcee does, waiting out another process's lock on it.

        A user who opens the checkpoint while the run goes on (h5py, a viewer) holds its
        HDF5 lock; the run waits up to :data:`LOCK_WAIT_S` seconds for it instead of
        dying on the first write, then raises naming the file.
        """
        delay, waited = 0.05, 0.0
        while True:
            try:
                return super().open(mode)
            except BlockingIOError:
                if waited >= LOCK_WAIT_S:
                    raise BlockingIOError(
                        f"checkpoint {self.filename} stayed locked by another process for "
                        f"{waited:.0f} s; close it and resume the run") from None
                _log.warning("checkpoint %s is locked by another process; waiting",
                             self.filename)
                time.sleep(delay)
                waited += delay
                delay = min(2.0 * delay, 2.0)

    def flush(self) -> None:
        """Write buffered steps; the checkpoint attribute is written last."""
        self._last_flush = time.monotonic()
        if not self._coords:
            return
        n = len(self._coords)
        with self.open("a") as f:
            g = f[self.name]
            it = int(g.attrs["iteration"])
            if g["chain"].shape[0] < it + n:
                g["chain"].resize(it + n, axis=0)
                g["log_prob"].resize(it + n, axis=0)
            g["chain"][it:it + n] = np.stack(self._coords)
            g["log_prob"][it:it + n] = np.stack(self._log_prob)
            g["accepted"][:] = self._accepted
            extra = None if self.extra_provider is None else self.extra_provider()
            g.attrs[_STEP] = self._step_record(it + n, self._random_state, self._accepted,
                                               extra)
            g.attrs["iteration"] = it + n
        self._coords, self._log_prob = [], []

    def get_value(self, name: str, flat: bool = False, thin: int = 1, discard: int = 0) -> Any:
        """The stored array ``name`` (emcee's ``get_value``) after a flush, buffered steps included.

        Parameters are those of :meth:`emcee.backends.Backend.get_value`.
        """
        self.flush()
        return super().get_value(name, flat=flat, thin=thin, discard=discard)

    @property
    def accepted(self) -> np.ndarray:
        """Accepted proposals per walker (W,), buffered steps included (flushes first)."""
        self.flush()
        return super().accepted

    def get_last_sample(self) -> Any:
        """The last step as an emcee ``State``, after a flush."""
        self.flush()
        return super().get_last_sample()


def write_meta(filename: str | Path, meta: dict[str, Any]) -> None:
    """Store run metadata (JSON values and numeric numpy arrays) in the checkpoint.

    Parameters
    ----------
    filename : str or Path
        The HDF5 checkpoint (created if missing).
    meta : dict
        JSON values, tuples (stored as lists) and numeric arrays.
    """
    text = json.dumps(_encode(meta))
    with h5py.File(filename, "a") as f:
        for name in _PICKLED[:1]:
            if name in f.attrs:
                _refuse_pickled(filename, "the file")
        # a dataset, not an attribute: attributes are limited to 64 kB and a discrepancy
        # fit's covariance is larger
        if _META in f:
            del f[_META]
        f.create_dataset(_META, data=text, dtype=h5py.string_dtype("utf-8"))
        f.attrs[_FORMAT_ATTR] = CHECKPOINT_FORMAT


def read_meta(filename: str | Path) -> dict[str, Any] | None:
    """The metadata stored by :func:`write_meta`, or None for a new/empty file.

    Raises
    ------
    ParameterError
        If the file is not HDF5, is of another checkpoint format (the pickled format 1
        is refused without being loaded) or its metadata is not checkpoint JSON.
    """
    path = Path(filename)
    if not path.exists():
        return None
    try:
        with h5py.File(path, "r") as f:
            if _PICKLED[0] in f.attrs:
                _refuse_pickled(path, "the file")
            version = f.attrs.get(_FORMAT_ATTR)
            raw = f[_META][()] if _META in f else None
    except OSError as exc:
        raise ParameterError(f"checkpoint {path} cannot be read as HDF5 ({exc}); delete it "
                             "to start afresh") from exc
    if raw is None:
        return None
    if version is None or int(version) != CHECKPOINT_FORMAT:
        raise ParameterError(f"checkpoint {path} has format {version}, this bayeshyst reads "
                             f"format {CHECKPOINT_FORMAT}; delete it to start afresh")
    meta = _loads(raw, path, "the run's metadata")
    if not isinstance(meta, dict):
        raise ParameterError(f"checkpoint {path}: the run's metadata is not a JSON object; "
                             "delete it to start afresh")
    return meta


def check_fingerprint(filename: str | Path, stored: dict[str, Any], wanted: dict[str, Any]) -> None:
    """Refuse to resume a checkpoint written for a different run."""
    diff = sorted(k for k in set(stored) | set(wanted) if stored.get(k) != wanted.get(k))
    if diff:
        show = {k: (stored.get(k), wanted.get(k)) for k in diff[:4]}
        raise ParameterError(
            f"checkpoint {filename} was written for a different run (differs in "
            f"{', '.join(diff)}: stored vs now {json.dumps(show, default=str)[:300]}); "
            "use another path or delete it"
        )
