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
"""

from __future__ import annotations

import json
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from emcee.backends import HDFBackend

from bayeshyst.errors import ParameterError

__all__ = ["CheckpointBackend", "check_fingerprint", "read_meta", "write_meta"]


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
        raw = g.attrs.get("checkpoint")
        return None if raw is None else pickle.loads(np.asarray(raw).tobytes())

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
            g.attrs["checkpoint"] = np.void(pickle.dumps(
                {"iteration": 0, "random_state": None, "accepted": np.zeros(nwalkers, int)}))

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
            g.attrs["checkpoint"] = np.void(pickle.dumps(
                {"iteration": it + n, "random_state": self._random_state,
                 "accepted": np.array(self._accepted), "extra": extra}))
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
    """Store run metadata (JSON-serialisable except numpy arrays) as a file attribute."""
    blob = pickle.dumps(meta)
    with h5py.File(filename, "a") as f:
        f.attrs["bayeshyst_meta"] = np.void(blob)


def read_meta(filename: str | Path) -> dict[str, Any] | None:
    """The metadata stored by :func:`write_meta`, or None for a new/empty file."""
    path = Path(filename)
    if not path.exists():
        return None
    try:
        with h5py.File(path, "r") as f:
            raw = f.attrs.get("bayeshyst_meta")
    except OSError as exc:
        raise ParameterError(f"checkpoint {path} cannot be read as HDF5 ({exc}); delete it "
                             "to start afresh") from exc
    return None if raw is None else pickle.loads(np.asarray(raw).tobytes())


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
