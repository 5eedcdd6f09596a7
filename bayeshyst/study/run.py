"""Run a study on Dask distributed: :func:`run_study`.

Every (dataset, model, likelihood, frequency, seed) fit is one Dask task running
:func:`bayeshyst.study.tasks.execute`. By default a ``distributed.LocalCluster`` with one
single-threaded worker process per core runs them; ``scheduler="tcp://host:port"``
submits to a running cluster instead (its workers need bayeshyst installed, and nothing
else: data travel with the tasks, posteriors come back as bytes).

As each fit completes, the client writes its posterior and its record under
``OUT/fits/`` (atomically, posterior first), so the study can be stopped at any moment:
a re-run loads the records whose inputs hash to the same name and submits only the
rest. A fit that fails is a row with its error; a worker that dies has its fits
re-run elsewhere by the scheduler (after ``distributed.scheduler.allowed-failures``
deaths a fit is recorded as failed and the study goes on).
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import frequency_label
from bayeshyst.errors import DataError, ParameterError
from bayeshyst.files import atomic_path
from bayeshyst.study.rows import failed_row, fit_record, read_record, write_record
from bayeshyst.study.spec import DatasetSpec, Study, load_dataset
from bayeshyst.study.summary import DatasetRanking, FrequencySummary, summarise
from bayeshyst.study.tasks import FitOutcome, StudyTask, data_digest, execute

__all__ = ["StudyResult", "plan_study", "run_study"]


@dataclass(frozen=True)
class PlannedData:
    """A dataset as the client read it: its groups by frequency, or why it gave none."""

    spec: DatasetSpec
    groups: dict[float | None, Dataset] = field(default_factory=dict)
    error: str | None = None


@dataclass(frozen=True)
class StudyResult:
    """What a study produced.

    Attributes
    ----------
    study : Study
    rows : tuple of dict
        The table, one row per planned fit, in plan order (dataset, frequency, model,
        likelihood, seed); keys :data:`~bayeshyst.study.rows.TABLE_COLUMNS`.
    rankings : tuple of DatasetRanking
        Best model per dataset and frequency.
    by_frequency : tuple of FrequencySummary
        Model selection per frequency across datasets.
    n_run, n_reused : int
        Fits run now, and fits whose stored result was reused.
    runtime_s : float
    out_dir : str
    cluster : str
        Where the fits ran (``"serial"``, ``"LocalCluster(2 workers)"``, the scheduler).
    """

    study: Study
    rows: tuple[dict[str, Any], ...]
    rankings: tuple[DatasetRanking, ...]
    by_frequency: tuple[FrequencySummary, ...]
    n_run: int
    n_reused: int
    runtime_s: float
    out_dir: str
    cluster: str

    @property
    def failed(self) -> tuple[dict[str, Any], ...]:
        """Rows of fits without scores."""
        return tuple(r for r in self.rows if r["status"] != "ok")

    def __str__(self) -> str:
        n_conv = sum(bool(r["converged"]) for r in self.rows if r["status"] == "ok")
        n_ok = len(self.rows) - len(self.failed)
        lines = [f"{self.study}", f"{len(self.rows)} fits: {n_ok} ok ({n_conv} converged), "
                 f"{len(self.failed)} failed; {self.n_run} run now on {self.cluster}, "
                 f"{self.n_reused} reused; {self.runtime_s:.1f} s", ""]
        lines += [str(s) + "\n" for s in self.by_frequency]
        # one line per distinct error (an unreadable dataset fails every model the same way)
        by_error: dict[str, list[str]] = {}
        for r in self.failed:
            f = "" if r["frequency_hz"] is None else f" · {r['frequency_hz']:g} Hz"
            by_error.setdefault(r["error"], []).append(f"{r['dataset']} · {r['model']}{f}")
        for err, fits in by_error.items():
            lines.append(f"failed ({len(fits)} fit{'s' if len(fits) > 1 else ''}: "
                         f"{fits[0]}{', …' if len(fits) > 1 else ''}): {err}")
        return "\n".join(lines).rstrip()


def _source(spec: DatasetSpec) -> str:
    return spec.path if spec.path is not None else f"measured:{spec.measured}"


def _read(spec: DatasetSpec, freqs: tuple[float, ...] | None) -> PlannedData:
    try:
        data = load_dataset(spec)
    except DataError as exc:
        return PlannedData(spec, error=str(exc))
    groups = data.by_frequency()
    if freqs is not None:
        keep = {f: d for f, d in groups.items()
                if f is not None and any(math.isclose(f, g, rel_tol=1e-9) for g in freqs)}
        if not keep:
            have = [frequency_label(f) for f in groups]
            return PlannedData(spec, error=(
                f"{spec.source}: no records at the study's frequencies_hz "
                f"{[float(f) for f in freqs]}; the dataset has {have}"))
        groups = keep
    return PlannedData(spec, groups)


def plan_study(study: Study) -> tuple[list[PlannedData], list[StudyTask | dict[str, Any]]]:
    """Read the datasets and list every fit in table order.

    Returns
    -------
    (list of PlannedData, list)
        The datasets as read, and one entry per fit: a :class:`StudyTask`, or a failed
        row (dict) for a dataset that could not be read.
    """
    planned = [_read(spec, study.frequencies_hz) for spec in study.datasets]
    plan: list[StudyTask | dict[str, Any]] = []
    for pd in planned:
        for f, sub in (pd.groups.items() if pd.error is None else [(None, None)]):
            digest = data_digest(sub) if sub is not None else ""
            for m in study.models:
                for lik in study.likelihoods:
                    for seed in study.seeds:
                        if pd.error is not None:
                            plan.append(failed_row(
                                None, dataset=pd.spec.label, source=_source(pd.spec), model=m,
                                likelihood=lik, seed=seed, frequency_hz=None,
                                error=pd.error))
                            continue
                        plan.append(StudyTask(pd.spec.label, m, lik, f, seed, digest,
                                              replace(study.settings, likelihood=lik)))
    return planned, plan


@contextmanager
def _dask_client(scheduler: str | None, n_workers: int | None,
                 client: Any) -> Iterator[tuple[Any, str]]:
    """A ``distributed.Client``: the caller's, one connected to ``scheduler``, or a new one.

    The new one is of a new LocalCluster with ``n_workers`` single-threaded worker
    processes.
    """
    if client is not None:
        yield client, f"the given client ({client.scheduler.address})"
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:  # pragma: no cover - a dependency of bayeshyst
        raise ParameterError(f"bayeshyst study needs dask distributed ({exc}); "
                             f"pip install distributed") from None
    if scheduler is not None:
        try:
            c = Client(scheduler, timeout="30s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise ParameterError(f"cannot connect to the Dask scheduler {scheduler!r}: "
                                 f"{exc}") from None
        with c:
            yield c, f"the cluster at {scheduler}"
        return
    import dask

    n = n_workers or os.cpu_count() or 1
    # one single-threaded process per core: the fits are CPU-bound Python + numba, so
    # threads would share one GIL; no dashboard unless bokeh is there to serve it.
    # A worker's own periodic work (statistical profiler every 10 ms, event-loop tick
    # every 20 ms, memory monitor every 100 ms) takes the GIL from the fit: measured
    # (benchmarks/RESULTS.md) it made the fits 39 % slower than without Dask, 15 % with
    # these settings. Fits last seconds to hours, so 1 s ticks lose nothing.
    with dask.config.set(WORKER_CONFIG), \
            LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                         dashboard_address=":0" if _has_bokeh() else None) as cluster, \
            Client(cluster) as c:
        yield c, f"LocalCluster({n} worker{'s' if n != 1 else ''})"


WORKER_CONFIG = {"distributed.worker.profile.enabled": False,
                 "distributed.admin.tick.interval": "1s",
                 "distributed.worker.memory.monitor-interval": "1s"}
"""Dask settings of the LocalCluster a study starts (see ``_dask_client``); workers of
a cluster of your own take them as ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False``
etc. in their environment."""


def _has_bokeh() -> bool:
    try:
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


def _identity(x: Any) -> Any:
    return x


def _worker_stack() -> dict[str, str]:
    """Versions a worker computes with (run on each worker by :func:`_check_workers`)."""
    import emcee
    import numba
    import numpy
    import scipy

    from bayeshyst._version import __version__

    return {"bayeshyst": __version__, "numpy": numpy.__version__, "scipy": scipy.__version__,
            "numba": numba.__version__, "emcee": emcee.__version__}


def _check_workers(client: Any, say: Callable[[str], None]) -> None:
    """Refuse a cluster whose workers cannot import bayeshyst; warn when versions differ.

    Warn when the workers' versions differ from the client's: the same seeds give the
    same numbers only on one stack.
    """
    if not client.scheduler_info().get("workers"):
        say("no workers connected yet: the fits wait until workers join")
        return
    try:
        stacks = client.run(_worker_stack)
    except ImportError as exc:
        raise ParameterError(f"the cluster's workers cannot run bayeshyst ({exc}); install "
                             f"bayeshyst and its dependencies in the workers' environment"
                             ) from None
    mine = _worker_stack()
    for worker, stack in stacks.items():
        diff = {k: v for k, v in stack.items() if mine.get(k) != v}
        if diff:
            say(f"warning: worker {worker} runs {diff} (this client: "
                f"{ {k: mine[k] for k in diff} }); results may differ from a run elsewhere")


def run_study(
    study: Study,
    out_dir: str | os.PathLike[str],
    *,
    scheduler: str | None = None,
    n_workers: int | None = None,
    client: Any = None,
    serial: bool = False,
    retry_failed: bool = False,
    progress: bool = True,
    on_result: Callable[[dict[str, Any], Any], None] | None = None,
) -> StudyResult:
    """Run every pending fit of ``study``; gather the table and model selection across datasets.

    Each fit's posterior and record are stored under ``out_dir/fits/`` as it completes
    (what a rerun resumes from). The study's tables, figures and ``summary.json`` are
    written by :func:`bayeshyst.outputs.study_outputs.write_study_outputs`, given the
    result (``bayeshyst study`` does both).

    Parameters
    ----------
    study : Study
        From :func:`~bayeshyst.study.spec.read_study`.
    out_dir : path
        ``fits/`` (one posterior + record per fit) and ``work/`` (checkpoints of running
        fits, removed once every fit finished).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:port``).
    n_workers : int, optional
        Worker processes of the LocalCluster started when no scheduler is given
        (default: one per core).
    client : distributed.Client, optional
        Use this client (and its cluster) as is.
    serial : bool
        Run the fits one after the other in this process, without Dask (same numbers).
    retry_failed : bool
        Run again the fits whose stored result is a failure (by default a failed fit,
        like a finished one, is not repeated: its inputs and seed are the same).
    progress : bool
        One line per fit on stderr.
    on_result : callable, optional
        Called as ``on_result(row, client)`` after each fit run now is stored (the
        client is None in serial mode).

    Returns
    -------
    StudyResult
    """
    given = [x is not None for x in (scheduler, client)] + [serial]
    if sum(given) > 1:
        raise ParameterError("give at most one of scheduler, client and serial=True")
    if n_workers is not None and (int(n_workers) != n_workers or n_workers < 1):
        raise ParameterError(f"n_workers must be a positive integer, got {n_workers!r}")
    t0 = time.perf_counter()
    out = Path(out_dir).resolve()
    fits_dir, work_root = out / "fits", out / "work"
    fits_dir.mkdir(parents=True, exist_ok=True)
    planned, plan = plan_study(study)
    sources = {pd.spec.label: _source(pd.spec) for pd in planned}
    groups = {(pd.spec.label, f): d for pd in planned for f, d in pd.groups.items()}
    records: dict[str, dict[str, Any]] = {}
    todo: list[StudyTask] = []
    for item in plan:
        if isinstance(item, dict):
            continue
        rec = read_record(fits_dir / f"{item.name}.json", item)
        if rec is not None and not (retry_failed and rec.get("failure")):
            records[item.name] = rec
        else:
            todo.append(item)
    n_tasks = sum(isinstance(x, StudyTask) for x in plan)
    say = (lambda s: print(s, file=sys.stderr, flush=True)) if progress else (lambda s: None)
    unreadable = [pd for pd in planned if pd.error is not None]
    say(f"bayeshyst study {study.name!r}: {n_tasks} fits planned, {n_tasks - len(todo)} "
        f"already done, {len(todo)} to run"
        + (f"; {len(unreadable)} dataset(s) unreadable" if unreadable else ""))
    for pd in unreadable:
        say(f"  unreadable: {pd.error}")
    infra: dict[str, dict[str, Any]] = {}
    done_now = 0

    def store(task: StudyTask, outcome: FitOutcome | None, error: str | None,
              client_: Any) -> None:
        nonlocal done_now
        n_rec = len(groups[(task.dataset, task.frequency_hz)].records)
        if outcome is None:
            # the fit never returned (lost worker, cancelled): not stored, so a re-run
            # tries it again
            row = failed_row(task, dataset=task.dataset, source=sources[task.dataset],
                             model=task.model, likelihood=task.likelihood, seed=task.seed,
                             frequency_hz=task.frequency_hz, error=error or "lost")
            row["n_records"] = n_rec
            infra[task.name] = row
        else:
            posterior = None
            if outcome.netcdf is not None:
                nc = fits_dir / f"{task.name}.nc"
                with atomic_path(nc) as tmp:
                    tmp.write_bytes(outcome.netcdf)
                posterior = f"fits/{nc.name}"
            rec = fit_record(outcome, sources[task.dataset], n_rec, posterior)
            write_record(fits_dir / f"{task.name}.json", rec, task)
            shutil.rmtree(work_root / task.name, ignore_errors=True)
            records[task.name] = rec
            row = rec["row"]
        done_now += 1
        say(f"[{n_tasks - len(todo) + done_now}/{n_tasks}] {task.label()}: "
            + _state(row))
        if on_result is not None:
            on_result(row, client_)

    cluster = "nothing to run"
    if todo and serial:
        cluster = "serial"
        for task in todo:
            store(task, execute(task, groups[(task.dataset, task.frequency_hz)],
                                str(work_root / task.name)), None, None)
    elif todo:
        with _dask_client(scheduler, n_workers, client) as (c, cluster):
            say(f"running on {cluster}"
                + (f"; dashboard {c.dashboard_link}" if _has_bokeh() else ""))
            _check_workers(c, say)
            _run_on_dask(c, todo, groups, work_root, store)
    if work_root.is_dir() and not any(work_root.iterdir()):
        work_root.rmdir()  # every fit finished: no checkpoint left to resume from
    rows = []
    pointwise: dict[str, np.ndarray] = {}
    for item in plan:
        if isinstance(item, dict):
            rows.append(item)
            continue
        if item.name in records:
            rec = records[item.name]
            rows.append(rec["row"])
            if rec["row"]["status"] == "ok":
                pointwise[item.name] = np.asarray(rec["pointwise"], dtype=float)
        else:
            rows.append(infra[item.name])
    rankings, by_freq = summarise(rows, pointwise, study.models)
    return StudyResult(study, tuple(rows), rankings, by_freq, done_now,
                       n_tasks - len(todo), time.perf_counter() - t0, str(out), cluster)


def _state(row: dict[str, Any]) -> str:
    if row["status"] != "ok":
        return f"FAILED: {row['error']}"
    conv = "converged" if row["converged"] else "NOT converged"
    nrmse = row["nrmse_percent"]
    return (f"{conv}, elpd {row['elpd_loo']:.1f}"
            + ("" if nrmse is None else f", NRMSE {nrmse:.3f} %")
            + f" ({row['runtime_s']:.1f} s, {row['worker']})")


def _run_on_dask(client: Any, todo: list[StudyTask],
                 groups: dict[tuple[str, float | None], Dataset], work_root: Path,
                 store: Callable[[StudyTask, FitOutcome | None, str | None, Any], None]
                 ) -> None:
    from distributed import as_completed

    # each frequency group of a dataset goes to the cluster once, as a task of its own
    # (not scattered): if the worker holding it dies, the scheduler recomputes it from
    # the graph, which scattered data could not survive
    data_futures = {}
    for task in todo:
        k = (task.dataset, task.frequency_hz)
        if k not in data_futures:
            data_futures[k] = client.submit(_identity, groups[k], pure=False,
                                            key=f"bayeshyst-data-{task.data_sha256[:16]}-"
                                                f"{len(data_futures)}")
    futures = {client.submit(execute, task, data_futures[(task.dataset, task.frequency_hz)],
                             str(work_root / task.name), key=f"bayeshyst-fit-{task.name}",
                             pure=False): task for task in todo}
    for fut in as_completed(futures):
        task = futures[fut]
        if fut.status == "finished":
            store(task, fut.result(), None, client)
        elif fut.status == "cancelled":
            store(task, None, "the fit was cancelled on the cluster", client)
        else:
            exc = fut.exception()
            what = ("the workers running it died too often (distributed's "
                    "scheduler.allowed-failures)" if type(exc).__name__ == "KilledWorker"
                    else "it raised on the worker")
            store(task, None, f"the fit did not finish: {what}: {type(exc).__name__}: {exc}",
                  client)
        fut.release()
