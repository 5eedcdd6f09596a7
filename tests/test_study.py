"""``bayeshyst study``: a study file, fits on a Dask LocalCluster, resume, failures.

Oracles: the serial run (the same task function in this process, no Dask) for the
cluster runs — same seeds must give the same table, bit for bit, also when a worker is
killed mid-study; a direct call of the comparison's task function for one row; the
files on disk (a re-run must not touch them); the study file itself (every planned
(dataset, model, frequency) appears exactly once).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bayeshyst.cli import main
from bayeshyst.data import load
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.writers import write_csv
from bayeshyst.demo import bundled_data
from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.study_outputs import write_study_outputs
from bayeshyst.selection.tasks import CompareSettings, TaskSpec, derived_seed, run_task
from bayeshyst.study import plan_study, read_study, run_study
from bayeshyst.study.rows import TABLE_COLUMNS, VOLATILE_COLUMNS

distributed = pytest.importorskip("distributed")

MODELS = ("pi_play(n_operators=2)", "pi_play(n_operators=3)")
FREQS = {"act-a": (1.0, 10.0), "act-b": (10.0, 50.0)}


def _study_text(datasets: str, models: tuple[str, ...] = MODELS) -> str:
    return textwrap.dedent(f"""\
        name = "tiny"
        models = {json.dumps(list(models))}
        seed = 3

        [sampler]
        max_steps = 200
        first_chunk = 100
        max_refits = 0
        draws_per_chain = 10
        n_predictive_draws = 100
        """) + datasets


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two small datasets (two frequencies each, one shared), one unreadable file."""
    root = tmp_path_factory.mktemp("study")
    data = load(bundled_data("virtual_multifreq.csv", fallback_dir=root / "bundle"))
    for name, freqs in FREQS.items():
        write_csv(Dataset([r for r in data if r.frequency_hz in freqs], name=name),
                  root / "runs" / f"{name}.csv")
    (root / "runs" / "broken.csv").write_text("t,u,y\n0,0,0\n0.1,oops,1\n")
    (root / "study.toml").write_text(_study_text(
        '[[datasets]]\npath = "runs/act-*.csv"\n\n[[datasets]]\npath = "runs/broken.csv"\n'))
    return root


def _rows(out: Path) -> list[dict]:
    return json.loads((out / "table.json").read_text())["rows"]


def _stable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in VOLATILE_COLUMNS} for r in rows]


@pytest.fixture(scope="module")
def serial(files: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The study run through the command line, serially, with its HTML report."""
    out = tmp_path_factory.mktemp("serial") / "out"
    code = main(["study", str(files / "study.toml"), "--out", str(out), "--serial",
                 "--quiet", "--report"])
    assert code == 0
    return out


def test_table_has_every_planned_fit_once_and_the_bad_dataset_failed(serial: Path) -> None:
    rows = _rows(serial)
    with open(serial / "table.csv", newline="") as fh:
        csv_rows = list(csv.DictReader(fh))
    assert tuple(csv_rows[0]) == TABLE_COLUMNS and len(csv_rows) == len(rows)
    good = [(r["dataset"], r["model"], r["frequency_hz"]) for r in rows if r["status"] == "ok"]
    want = [(d, m, f) for d, fs in FREQS.items() for f in fs for m in MODELS]
    assert sorted(good) == sorted(want) and len(set(good)) == len(good)
    bad = [r for r in rows if r["dataset"] == "broken"]
    assert [r["model"] for r in bad] == list(MODELS)
    for r in bad:
        assert r["status"] == "failed" and r["elpd_loo"] is None
        # the message names the file, the line and the column, and what was wrong
        assert "broken.csv" in r["error"] and "line 3" in r["error"] and "'u'" in r["error"]
    summary = json.loads((serial / "summary.json").read_text())
    assert summary["n_failed"] == len(MODELS) and summary["n_fits"] == len(rows)
    assert (serial / "study.html").is_file()


def test_rows_are_the_comparison_task_on_that_frequency(serial: Path, files: Path) -> None:
    # independent path: read the dataset file, cut the frequency, call the task directly
    study = read_study(files / "study.toml")
    row = next(r for r in _rows(serial) if r["dataset"] == "act-b"
               and r["frequency_hz"] == 50.0 and r["model"] == MODELS[1])
    data = load(files / "runs" / "act-b.csv").select(50.0)
    res = run_task(data, TaskSpec(MODELS[1], "frequency", 50.0, True),
                   replace(study.settings, likelihood="gaussian"),
                   derived_seed(3, "act-b|gaussian"))
    assert row["elpd_loo"] == pytest.approx(float(np.sum(res.pointwise)), rel=1e-12)
    assert row["n_cycles"] == res.pointwise.size
    assert row["nrmse_percent"] == pytest.approx(res.overall.nrmse_percent, rel=1e-12)
    # the stored pointwise values add up to the table's elpd
    record = json.loads((serial / "fits" / f"{row['task']}.json").read_text())
    assert sum(record["pointwise"]) == pytest.approx(row["elpd_loo"], rel=1e-12)
    assert (serial / row["posterior"]).is_file()


# slow (2 min of a two-process cluster)
@pytest.mark.slow
def test_two_worker_cluster_gives_the_serial_table_even_when_a_worker_is_killed(
        serial: Path, files: Path, tmp_path: Path) -> None:
    killed: list[str] = []

    def kill_a_busy_worker(row: dict, client: object) -> None:
        if killed:
            return
        pids = client.run(os.getpid)
        busy = [w for w, keys in client.processing().items() if keys]
        if busy:  # SIGKILL: no clean-up, as when a node is lost
            os.kill(pids[busy[0]], signal.SIGKILL)
            killed.append(busy[0])

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        result = run_study(read_study(files / "study.toml"), tmp_path / "out", client=client,
                           progress=False, on_result=kill_a_busy_worker)
    write_study_outputs(result, tmp_path / "out")
    assert killed, "no worker was busy when the first fit came back"
    assert result.n_run == len(MODELS) * 4 and not [r for r in result.failed
                                                    if r["dataset"] != "broken"]
    assert _stable(_rows(tmp_path / "out")) == _stable(_rows(serial))


def test_rerun_does_no_work_and_a_lost_result_is_the_only_fit_run_again(
        serial: Path, files: Path, tmp_path: Path) -> None:
    study = read_study(files / "study.toml")
    fits = sorted((serial / "fits").iterdir())
    stamps = {p: p.stat().st_mtime_ns for p in fits}
    outputs = {p: p.stat().st_mtime_ns for p in serial.iterdir() if p.is_file()}
    again = run_study(study, serial, progress=False)
    assert again.n_run == 0 and again.cluster == "nothing to run"  # no cluster started
    assert {p: p.stat().st_mtime_ns for p in sorted((serial / "fits").iterdir())} == stamps
    # running a study writes its fits only: the tables and summary are the writer's
    assert "summary.json" in {p.name for p in outputs}
    assert {p: p.stat().st_mtime_ns for p in serial.iterdir() if p.is_file()} == outputs
    # an interrupted study: copy the results, drop one, run again → only that one runs
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(serial, out)
    victim = next(out.glob("fits/act-a__*10Hz*.json"))
    victim.unlink()
    resumed = run_study(study, out, serial=True, progress=False)
    write_study_outputs(resumed, out)
    assert resumed.n_run == 1 and resumed.n_reused == len(MODELS) * 4 - 1
    assert _stable(_rows(out)) == _stable(_rows(serial))


def test_task_names_follow_inputs_and_settings(files: Path, tmp_path: Path) -> None:
    study = read_study(files / "study.toml")
    names = [t.name for t in plan_study(study)[1] if not isinstance(t, dict)]
    assert len(set(names)) == len(names) == len(MODELS) * 4
    for change in ({"max_steps": 300}, {"moves": "de"}):
        other = replace(study, settings=replace(
            study.settings, sampler=study.settings.sampler.replace(**change)))
        assert not set(names) & {t.name for t in plan_study(other)[1]
                                 if not isinstance(t, dict)}, change
    # the progress bar and the checkpoint are not what a fit's result depends on
    same = replace(study, settings=replace(
        study.settings, sampler=study.settings.sampler.replace(progress=True)))
    assert [t.name for t in plan_study(same)[1] if not isinstance(t, dict)] == names
    # the same file content under a new path is the same task; changed values are not
    (tmp_path / "runs").mkdir()
    for p in (files / "runs").glob("act-*.csv"):
        (tmp_path / "runs" / p.name).write_bytes(p.read_bytes())
        sidecar = p.with_suffix(".json")
        if sidecar.exists():
            (tmp_path / "runs" / sidecar.name).write_bytes(sidecar.read_bytes())
    (tmp_path / "s.toml").write_text(_study_text('[[datasets]]\npath = "runs/act-*.csv"\n'))
    moved = [t.name for t in plan_study(read_study(tmp_path / "s.toml"))[1]]
    assert moved == names
    # one displacement sample of act-a's first record (1 Hz) moves by 1 nm
    lines = (tmp_path / "runs" / "act-a.csv").read_text().splitlines()
    cells = lines[1].split(",")
    assert lines[0].split(",")[2] == "y"
    cells[2] = repr(float(cells[2]) + 1e-3)
    lines[1] = ",".join(cells)
    (tmp_path / "runs" / "act-a.csv").write_text("\n".join(lines) + "\n")
    changed = [t.name for t in plan_study(read_study(tmp_path / "s.toml"))[1]]
    differ = [b for a, b in zip(changed, names, strict=True) if a != b]
    assert len(differ) == len(MODELS) and all(n.startswith("act-a__") and "__1Hz__" in n
                                              for n in differ)


@pytest.mark.parametrize(("body", "message"), [
    ('models = ["bouc_wen"]\n[[datasets]]\npath = "x.csv"\nwarmpu = 3\n',
     "unknown key 'warmpu' (did you mean 'warmup'?)"),
    ('models = ["no_such_model"]\n[[datasets]]\npath = "x.csv"\n', "no_such_model"),
    ('models = ["bouc_wen"]\nseed = 1\nseeds = [1, 2]\n[[datasets]]\npath = "x.csv"\n',
     "give 'seed' or 'seeds', not both"),
    ('models = ["bouc_wen"]\n[sampler]\nmax_steps = 5\n[[datasets]]\npath = "x.csv"\n',
     "max_steps must be an integer >= 10, got 5"),
    ('models = ["bouc_wen"]\n[sampler]\nmax_step = 50\n[[datasets]]\npath = "x.csv"\n',
     "unknown key 'max_step' (did you mean 'max_steps'?)"),
    ('models = ["bouc_wen"]\n[sampler]\nmoves = "strech"\n[[datasets]]\npath = "x.csv"\n',
     "unknown moves 'strech' (did you mean 'stretch'?)"),
    ('models = ["bouc_wen"]\n[[datasets]]\nmeasured = "mr_damper"\noptions = {current = 1}\n',
     "unknown key 'current' (did you mean 'current_a'?)"),
    ('models = ["bouc_wen"]\n', "expected at least one [[datasets]] table"),
    ('models = ["bouc_wen"\n', "not valid TOML"),
])
def test_bad_study_files_are_refused_with_the_key_named(tmp_path: Path, body: str,
                                                        message: str, capsys) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises((ParameterError, ModelError, ValueError)) as err:
        read_study(path)
    assert message in str(err.value) and str(path) in str(err.value)
    out = tmp_path / "out"
    assert main(["study", str(path), "--out", str(out), "--quiet"]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_sampler_table_maps_onto_the_sampler_and_scoring_settings(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('models = ["bouc_wen"]\n[sampler]\nmoves = "de"\nn_walkers = 20\n'
                    'max_steps = 300\nfirst_chunk = 50\ndraws_per_chain = 7\n'
                    'n_predictive_draws = 60\nmax_refits = 1\ngp_n_train = 99\n'
                    '[[datasets]]\npath = "x.csv"\n')
    st = read_study(path)
    s = st.settings
    assert (s.sampler.moves, s.sampler.n_walkers, s.sampler.max_steps,
            s.sampler.first_chunk) == ("de", 20, 300, 50)
    assert (s.draws_per_chain, s.n_lofo_draws, s.max_refits, s.gp_n_train) == (7, 60, 1, 99)
    # keys not given keep the defaults of every command
    default = read_study(_write(tmp_path / "d.toml", 'models = ["bouc_wen"]\n'
                                '[[datasets]]\npath = "x.csv"\n')).settings
    assert default.sampler == SamplerSettings() and default == CompareSettings()
    assert st.to_dict()["sampler"] == {
        "moves": "de", "n_walkers": 20, "max_steps": 300, "first_chunk": 50,
        "draws_per_chain": 7, "n_predictive_draws": 60, "max_refits": 1, "gp_n_train": 99}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_unmatched_glob_is_a_failed_dataset_not_a_bad_file(tmp_path: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text(_study_text('[[datasets]]\npath = "nothing/*.csv"\n'))
    plan = plan_study(read_study(path))[1]
    assert len(plan) == len(MODELS) and all(isinstance(p, dict) for p in plan)
    assert all("matches no file" in p["error"] for p in plan)


class _FakeClient:
    """The two calls ``_check_workers`` makes, answered as a cluster would."""

    def __init__(self, workers: dict, stacks: dict | Exception) -> None:
        self._workers, self._stacks = workers, stacks

    def scheduler_info(self) -> dict:
        return {"workers": self._workers}

    def run(self, fn: object) -> dict:
        if isinstance(self._stacks, Exception):
            raise self._stacks
        return self._stacks


def test_workers_without_bayeshyst_are_refused_and_other_versions_named() -> None:
    from bayeshyst.study.run import _check_workers, _worker_stack

    said: list[str] = []
    with pytest.raises(ParameterError, match="cannot run bayeshyst"):
        _check_workers(_FakeClient({"w": {}}, ModuleNotFoundError("No module named "
                                                                  "'bayeshyst'")), said.append)
    mine = _worker_stack()
    _check_workers(_FakeClient({"a": {}, "b": {}}, {"a": mine, "b": {**mine, "numpy": "0.1"}}),
                   said.append)
    assert len(said) == 1 and "worker b" in said[0] and "'numpy': '0.1'" in said[0]
    _check_workers(_FakeClient({}, {}), said.append)
    assert "no workers connected yet" in said[-1]
