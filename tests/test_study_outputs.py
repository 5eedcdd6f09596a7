"""Study summary and outputs: ``summarise``, the CSVs, the figures and ``study.html``.

Everything is built by hand from synthetic pointwise elpd whose answer is known (model
A scores −1 on every cycle and B −2, so A wins everywhere by exactly the number of
cycles, with zero standard error) or computed here directly with numpy (paired
differences, seed means, seed spread). The outputs are then read back independently:
``csv`` for the tables, the PNG magic bytes, base64 for the embedded figures and
``html.parser`` for what a browser would see.
"""

from __future__ import annotations

import base64
import csv
import json
import math
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bayeshyst.errors import ParameterError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs.assemble import study_output_figures
from bayeshyst.outputs.study_html import SECTIONS, study_html
from bayeshyst.outputs.study_outputs import write_study_outputs
from bayeshyst.plotting.study import (
    best_model_figure,
    model_colors,
    plot_best_model,
    plot_scores_vs_frequency,
    scores_vs_frequency_figure,
    study_figures,
)
from bayeshyst.selection.tasks import CompareSettings
from bayeshyst.study.rows import TABLE_COLUMNS, failed_row
from bayeshyst.study.run import StudyResult
from bayeshyst.study.spec import DatasetSpec, Study
from bayeshyst.study.summary import summarise

EVIL = "<script>alert(1)</script>"
MB = "B<script>alert(2)</script>"  # a model spec is text from the study file too
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- builders
def _study(datasets: list[str], models: tuple[str, ...], seeds: tuple[int, ...] = (0,),
           likelihoods: tuple[str, ...] = ("gaussian",)) -> Study:
    specs = tuple(DatasetSpec(d, f"/data/{d}.csv", None, (), f"datasets[{i}]")
                  for i, d in enumerate(datasets))
    return Study("synthetic", "/data/study.toml", specs, models, likelihoods, seeds, None,
                 CompareSettings(sampler=SamplerSettings(max_steps=100, first_chunk=50)))


def _ok_row(ds: str, model: str, f: float | None, seed: int, pw: np.ndarray, *,
            lik: str = "gaussian", nrmse: float = 1.0, converged: bool = True
            ) -> dict[str, Any]:
    task = f"{ds}__{model}__{f}__{lik}__s{seed}"
    row: dict[str, Any] = dict.fromkeys(TABLE_COLUMNS)
    row.update(dataset=ds, source=f"/data/{ds}.csv", model=model, likelihood=lik, seed=seed,
               frequency_hz=f, status="ok", n_records=1, n_cycles=int(pw.size),
               elpd_loo=float(pw.sum()), elpd_se=float(math.sqrt(pw.size * np.var(pw))),
               nrmse_percent=nrmse, converged=converged, n_params=4, n_refits=0,
               failed_simulations=0, runtime_s=0.5, worker="test:1",
               posterior=f"fits/{task}.nc", task=task, warnings="", error=None)
    return row


def _failed_fit(ds: str, model: str, f: float | None, seed: int, error: str, *,
                lik: str = "gaussian") -> dict[str, Any]:
    """A fit that ran on readable data and failed (it has records and a frequency)."""
    row = failed_row(None, dataset=ds, source=f"/data/{ds}.csv", model=model,
                     likelihood=lik, seed=seed, frequency_hz=f, error=error)
    row.update(n_records=1, task=f"{ds}__{model}__{f}__{lik}__s{seed}", runtime_s=0.1)
    return row


def _unreadable(ds: str, model: str, seed: int, error: str) -> dict[str, Any]:
    return failed_row(None, dataset=ds, source=f"/data/{ds}.csv", model=model,
                      likelihood="gaussian", seed=seed, frequency_hz=None, error=error)


def _result(study: Study, rows: list[dict[str, Any]], pointwise: dict[str, np.ndarray]
            ) -> StudyResult:
    rankings, by_freq = summarise(rows, pointwise, study.models)
    return StudyResult(study, tuple(rows), rankings, by_freq, len(rows), 0, 12.5,
                       "/tmp/out", "LocalCluster(2 workers)")


def _add(rows: list[dict[str, Any]], pointwise: dict[str, np.ndarray], row: dict[str, Any],
         pw: np.ndarray) -> None:
    rows.append(row)
    pointwise[row["task"]] = pw


def _summary_at(result: StudyResult, f: float | None) -> Any:
    (s,) = [s for s in result.by_frequency if s.frequency_hz == f]
    return s


def _ranking_at(result: StudyResult, ds: str, f: float | None) -> Any:
    (d,) = [d for d in result.rankings if d.dataset == ds and d.frequency_hz == f]
    return d


def _paired(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Oracle: sum of a − b and sqrt(n · population variance of a − b)."""
    d = a - b
    return float(d.sum()), float(np.sqrt(d.size * d.var()))


# ------------------------------------------------------------------- the known answer
@pytest.fixture(scope="module")
def constant() -> StudyResult:
    """A scores −1 and B −2 on every cycle of 3 datasets (4, 5, 6 cycles) at 10 Hz."""
    study = _study(["d1", "d2", "d3"], ("A", "B"))
    rows: list[dict[str, Any]] = []
    pw: dict[str, np.ndarray] = {}
    for ds, n in (("d1", 4), ("d2", 5), ("d3", 6)):
        for model, value in (("A", -1.0), ("B", -2.0)):
            _add(rows, pw, _ok_row(ds, model, 10.0, 0, np.full(n, value)), np.full(n, value))
    return _result(study, rows, pw)


def test_summarise_constant_scores_known_answer(constant: StudyResult) -> None:
    s = _summary_at(constant, 10.0)
    assert s.best == "A"
    assert s.datasets == ("d1", "d2", "d3") and s.incomplete == ()
    a, b = s.models
    assert (a.model, a.wins, a.n_datasets) == ("A", 3, 3)
    assert (b.model, b.wins) == ("B", 0)
    assert a.elpd_loo == pytest.approx(-15.0) and b.elpd_loo == pytest.approx(-30.0)
    assert a.delta_elpd == 0.0 and a.delta_se == 0.0
    assert b.delta_elpd == pytest.approx(-15.0)  # −(4 + 5 + 6) cycles × 1
    assert b.delta_se == pytest.approx(0.0, abs=1e-12)
    for d, n in zip(constant.rankings, (4, 5, 6), strict=True):
        assert d.best == "A" and d.failed == ()
        assert d.ranking[1].delta_elpd == pytest.approx(-n)
        assert d.ranking[1].delta_se == pytest.approx(0.0, abs=1e-12)


def test_best_model_cells_show_the_lead(constant: StudyResult) -> None:
    fig = best_model_figure(constant)
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    # lead over the runner-up = number of cycles (1 per cycle), se 0
    assert texts == ["Δ 4.0 ± 0.0", "Δ 5.0 ± 0.0", "Δ 6.0 ± 0.0"]
    colors = model_colors(["A", "B"])
    faces = {p.get_facecolor()[:3] for p in fig.axes[0].patches}
    from matplotlib.colors import to_rgb

    assert faces == {to_rgb(colors["A"])}
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == ["A", "B"]  # every model of the study, winner or not


def test_scores_vs_frequency_plots_per_cycle_values(constant: StudyResult) -> None:
    fig = scores_vs_frequency_figure(constant)
    ax_elpd, ax_err = fig.axes
    lines = {ln.get_gid(): ln for ln in ax_elpd.lines if ln.get_gid()}
    assert set(lines) == {f"{d}|{m}" for d in ("d1", "d2", "d3") for m in ("A", "B")}
    # elpd per cycle = −1 for A and −2 for B whatever the number of cycles
    for gid, ln in lines.items():
        assert np.allclose(ln.get_ydata(), -1.0 if gid.endswith("|A") else -2.0)
        assert np.allclose(ln.get_xdata(), 10.0)
    assert {ln.get_gid() for ln in ax_err.lines if ln.get_gid()} == set(lines)


# ------------------------------------------------------------- paired and seed-averaged
@pytest.fixture(scope="module")
def mixed() -> tuple[StudyResult, dict[str, np.ndarray]]:
    """Random pointwise elpd, two seeds, 1 and 10 Hz, one fit failure at 10 Hz, every fit
    failing at one (evilly named) dataset at 10 Hz, and one unreadable dataset; model B's
    name holds a script too."""
    rng = np.random.default_rng(7)
    study = _study(["d1", "d2", EVIL, "broken"], ("A", MB), seeds=(0, 1))
    rows: list[dict[str, Any]] = []
    pw: dict[str, np.ndarray] = {}
    n_cyc = {"d1": 6, "d2": 8, EVIL: 5}
    for ds in ("d1", "d2", EVIL):
        for f in (1.0, 10.0):
            # B is better at d1, worse elsewhere
            for model, shift in (("A", 0.0), (MB, 0.6 if ds == "d1" else -0.7)):
                for seed in (0, 1):
                    if f == 10.0 and ds == EVIL:
                        rows.append(_failed_fit(ds, model, f, seed, "simulation blew up "
                                                "<b>badly</b>"))
                        continue
                    if f == 10.0 and ds == "d2" and model == MB:
                        rows.append(_failed_fit(ds, model, f, seed, "sampler diverged"))
                        continue
                    x = rng.normal(-1.0 + shift, 0.5, n_cyc[ds])
                    nrmse = (2.0 if model == "A" else 1.3) + seed
                    _add(rows, pw, _ok_row(ds, model, f, seed, x, nrmse=nrmse,
                                           converged=not (model == MB and seed == 1)), x)
    for model in ("A", MB):
        for seed in (0, 1):
            rows.append(_unreadable("broken", model, seed, "broken.csv: line 3: not a number"))
    return _result(study, rows, pw), pw


def _mean_pw(pw: dict[str, np.ndarray], ds: str, model: str, f: float) -> np.ndarray:
    return np.mean([pw[f"{ds}__{model}__{f}__gaussian__s{s}"] for s in (0, 1)], axis=0)


def test_summarise_seed_average_and_paired_difference(
        mixed: tuple[StudyResult, dict[str, np.ndarray]]) -> None:
    result, pw = mixed
    for ds in ("d1", "d2"):
        d = _ranking_at(result, ds, 1.0)
        a, b = _mean_pw(pw, ds, "A", 1.0), _mean_pw(pw, ds, MB, 1.0)
        scores = {s.model: s for s in d.ranking}
        top, low = (a, b) if a.sum() >= b.sum() else (b, a)
        assert d.best == ("A" if a.sum() >= b.sum() else MB)
        assert scores["A"].elpd_loo == pytest.approx(a.sum())
        assert scores["A"].se == pytest.approx(np.sqrt(a.size * a.var()))
        delta, se = _paired(low, top)
        assert d.ranking[1].delta_elpd == pytest.approx(delta)
        assert d.ranking[1].delta_se == pytest.approx(se)
        for m in ("A", MB):
            totals = [pw[f"{ds}__{m}__1.0__gaussian__s{s}"].sum() for s in (0, 1)]
            assert scores[m].seed_sd == pytest.approx(np.std(totals, ddof=1))
            assert scores[m].n_seeds == 2
            # NRMSE: the mean over the seeds (2 or 1.3, + seed)
            assert scores[m].nrmse_percent == pytest.approx(2.5 if m == "A" else 1.8)
        assert scores["A"].converged and not scores[MB].converged


def test_summarise_pools_over_complete_datasets(
        mixed: tuple[StudyResult, dict[str, np.ndarray]]) -> None:
    result, pw = mixed
    s1 = _summary_at(result, 1.0)
    assert s1.datasets == ("d1", "d2", EVIL) and s1.incomplete == ()
    pooled = {m: np.concatenate([_mean_pw(pw, ds, m, 1.0) for ds in s1.datasets])
              for m in ("A", MB)}
    best = max(pooled, key=lambda m: pooled[m].sum())
    assert s1.best == best
    other = MB if best == "A" else "A"
    by = {m.model: m for m in s1.models}
    assert by["A"].elpd_loo == pytest.approx(pooled["A"].sum())
    assert by[MB].elpd_loo == pytest.approx(pooled[MB].sum())
    delta, se = _paired(pooled[other], pooled[best])
    assert by[other].delta_elpd == pytest.approx(delta)
    assert by[other].delta_se == pytest.approx(se)
    wins = [max(("A", MB), key=lambda m, ds=ds: _mean_pw(pw, ds, m, 1.0).sum())
            for ds in s1.datasets]
    assert by["A"].wins == wins.count("A") and by[MB].wins == wins.count(MB)
    assert by["A"].converged_fraction == 1.0 and by[MB].converged_fraction == 0.0


def test_summarise_leaves_out_datasets_where_a_model_failed(
        mixed: tuple[StudyResult, dict[str, np.ndarray]]) -> None:
    result, pw = mixed
    s10 = _summary_at(result, 10.0)
    # d2: B failed (both seeds); EVIL: every fit failed
    assert s10.datasets == ("d1",)
    assert s10.incomplete == ("d2", EVIL)
    by = {m.model: m for m in s10.models}
    for m in ("A", MB):  # pooled over d1 only
        assert by[m].elpd_loo == pytest.approx(_mean_pw(pw, "d1", m, 10.0).sum())
        assert by[m].n_datasets == 1
    d2 = _ranking_at(result, "d2", 10.0)
    assert [s.model for s in d2.ranking] == ["A"] and d2.failed == (MB,)
    evil = _ranking_at(result, EVIL, 10.0)
    assert evil.ranking == () and evil.best is None and set(evil.failed) == {"A", MB}
    # the unreadable dataset has no frequency to be ranked at
    assert "broken" not in {d.dataset for d in result.rankings}


def test_summarise_averages_only_the_seeds_that_succeeded() -> None:
    study = _study(["d1"], ("A", "B"), seeds=(0, 1))
    a0, a1, b0 = np.array([-1.0, -2.0, -3.0]), np.array([-1.5, -2.5, -2.0]), np.full(3, -4.0)
    rows: list[dict[str, Any]] = []
    pw: dict[str, np.ndarray] = {}
    _add(rows, pw, _ok_row("d1", "A", 5.0, 0, a0), a0)
    _add(rows, pw, _ok_row("d1", "A", 5.0, 1, a1), a1)
    _add(rows, pw, _ok_row("d1", "B", 5.0, 0, b0), b0)
    rows.append(_failed_fit("d1", "B", 5.0, 1, "lost"))
    (d,) = _result(study, rows, pw).rankings
    a, b = d.ranking
    assert a.elpd_loo == pytest.approx(((a0 + a1) / 2).sum())
    assert a.seed_sd == pytest.approx(np.std([a0.sum(), a1.sum()], ddof=1))
    assert b.n_seeds == 1 and math.isnan(b.seed_sd)
    assert b.elpd_loo == pytest.approx(b0.sum())
    delta, se = _paired(b0, (a0 + a1) / 2)
    assert (b.delta_elpd, b.delta_se) == (pytest.approx(delta), pytest.approx(se))


# ------------------------------------------------------------------------ the outputs
class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: set[str] = set()
        self.images: list[str] = []
        self.hrefs: list[str] = []
        self.section_ids: list[str] = []
        self.text: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.add(tag)
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src") or "")
        for key in ("href", "src"):
            if a.get(key):
                self.hrefs.append(a[key] or "")
        if tag == "section":
            self.section_ids.append(a.get("id") or "")

    def handle_data(self, data: str) -> None:
        self.text.append(data)


@pytest.fixture(scope="module")
def written(mixed: tuple[StudyResult, dict[str, np.ndarray]],
            tmp_path_factory: pytest.TempPathFactory) -> tuple[StudyResult, Path, dict]:
    result, _ = mixed
    out = tmp_path_factory.mktemp("study")
    summary = write_study_outputs(result, out, figures=study_output_figures(result),
                                  html=True)
    return result, out, summary


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def test_csv_tables(written: tuple[StudyResult, Path, dict]) -> None:
    result, out, _ = written
    header, body = _read_csv(out / "table.csv")
    assert header == list(TABLE_COLUMNS)
    assert len(body) == len(result.rows)
    for cells, row in zip(body, result.rows, strict=True):
        rec = dict(zip(header, cells, strict=True))
        assert rec["dataset"] == row["dataset"] and rec["model"] == row["model"]
        assert rec["status"] == row["status"]
        assert rec["frequency_hz"] == ("" if row["frequency_hz"] is None
                                       else str(row["frequency_hz"]))
    for name in ("table.csv", "by_frequency.csv", "best_by_dataset.csv"):
        _, cells = _read_csv(out / name)
        bad = {c for r in cells for c in r if c.strip().lower() in
               ("nan", "inf", "-inf", "+inf", "infinity", "-infinity", "none")}
        assert not bad, f"{name}: {bad}"
    header, body = _read_csv(out / "by_frequency.csv")
    firsts = [dict(zip(header, r, strict=True)) for r in body if r[header.index("rank")] == "1"]
    assert [(float(r["frequency_hz"]), r["model"]) for r in firsts] == [
        (s.frequency_hz, s.best) for s in result.by_frequency]


def test_figures_written_and_embedded(written: tuple[StudyResult, Path, dict]) -> None:
    _, out, summary = written
    pngs = [out / "figures" / "best_model.png", out / "figures" / "scores_vs_frequency.png"]
    for p in pngs:
        assert p.read_bytes().startswith(PNG_MAGIC)
    assert summary["files"]["figures"] == ["figures/best_model.png",
                                           "figures/scores_vs_frequency.png"]
    page = _Page()
    page.feed((out / "study.html").read_text(encoding="utf-8"))
    embedded = [base64.b64decode(src.split(",", 1)[1]) for src in page.images
                if src.startswith("data:image/png;base64,")]
    assert len(embedded) == len(page.images) == 2
    assert embedded == [p.read_bytes() for p in pngs]


def test_html_is_safe_and_complete(written: tuple[StudyResult, Path, dict]) -> None:
    result, out, _ = written
    html = (out / "study.html").read_text(encoding="utf-8")
    assert "<script" not in html.lower()
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "B&lt;script&gt;alert(2)&lt;/script&gt;" in html
    assert "&lt;b&gt;badly&lt;/b&gt;" in html and "<b>" not in html
    page = _Page()
    page.feed(html)
    assert "script" not in page.tags and "b" not in page.tags
    assert page.section_ids == [a for a, _ in SECTIONS]
    assert [h for h in page.hrefs if not h.startswith(("#", "data:image/png;base64,"))] == []
    text = " ".join(page.text)
    assert EVIL in text and MB in text  # shown to the reader as text
    words = text.replace("—", " ").lower().split()
    assert not {"nan", "inf", "-inf", "none"} & set(words)
    assert "sampler diverged" in text and "broken.csv: line 3: not a number" in text
    # the headline per frequency names the pooled best
    for s in result.by_frequency:
        assert f"{s.best} wins {s.models[0].wins} of" in text


def test_summary_json_lists_the_files(written: tuple[StudyResult, Path, dict]) -> None:
    result, out, summary = written
    on_disk = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert on_disk == summary
    files = on_disk["files"]
    assert files["html"] == "study.html"
    for f in [*files["table"], *files["by_frequency"], *files["best_by_dataset"],
              *files["figures"], files["html"]]:
        assert (out / f).is_file(), f
    assert on_disk["n_fits"] == len(result.rows)
    assert on_disk["n_failed"] == len(result.failed) == 4 + 4 + 2
    assert [b["best"] for b in on_disk["best_per_frequency"]] == [
        s.best for s in result.by_frequency]


def test_best_model_marks_failed_and_single_cells(
        mixed: tuple[StudyResult, dict[str, np.ndarray]]) -> None:
    result, _ = mixed
    fig = best_model_figure(result)
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert "all failed" in texts  # EVIL at 10 Hz
    assert any(t.startswith("only model") for t in texts)  # d2 at 10 Hz: B failed
    assert len(texts) == 6  # 3 ranked datasets × 2 frequencies; "broken" has no row
    labels = [t.get_text() for t in fig.axes[0].get_yticklabels()]
    assert labels[:2] == ["d1", "d2"] and len(labels) == 3


# -------------------------------------------------------------------------- edge cases
def test_figures_return_none_when_there_is_nothing(tmp_path: Path) -> None:
    study = _study(["broken"], ("A", "B"))
    rows = [_unreadable("broken", m, 0, "unreadable") for m in ("A", "B")]
    result = _result(study, rows, {})
    assert result.rankings == () and result.by_frequency == ()
    assert plot_best_model(result, tmp_path / "best.png") is None
    assert plot_scores_vs_frequency(result, tmp_path / "scores.png") is None
    assert list(tmp_path.iterdir()) == []
    # the figure functions refuse, and the study's figures leave both out
    with pytest.raises(ParameterError, match="no ranking"):
        best_model_figure(result)
    with pytest.raises(ParameterError, match="no model has a score"):
        scores_vs_frequency_figure(result)
    assert study_figures(result) == {} and study_output_figures(result) == {}
    html = study_html(result, {})
    assert "<script" not in html and "nan" not in html.lower().split()


def test_unknown_frequency_points_are_left_out_with_a_note() -> None:
    study = _study(["d1"], ("A", "B"))
    rows: list[dict[str, Any]] = []
    pw: dict[str, np.ndarray] = {}
    for f in (2.0, None):
        for m, v in (("A", -1.0), ("B", -3.0)):
            _add(rows, pw, _ok_row("d1", m, f, 0, np.full(4, v)), np.full(4, v))
    result = _result(study, rows, pw)
    fig = scores_vs_frequency_figure(result)
    xs = {ln.get_gid(): list(ln.get_xdata()) for ln in fig.axes[0].lines if ln.get_gid()}
    assert xs == {"d1|A": [2.0], "d1|B": [2.0]}
    assert "left out: 2 point(s) at unknown excitation frequency" in fig.get_supxlabel()
    grid = best_model_figure(result)
    assert [t.get_text() for t in grid.axes[0].get_xticklabels()] == ["2 Hz", "unknown"]


def test_large_study_stays_readable() -> None:
    """20 datasets × 10 frequencies: the figure grows so that cells and labels keep their
    size, and every cell is annotated."""
    names = [f"dataset-{i:02d}" for i in range(20)]
    study = _study(names, ("A", "B", "C"))
    freqs = [0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0]
    rows: list[dict[str, Any]] = []
    pw: dict[str, np.ndarray] = {}
    for i, ds in enumerate(names):
        for f in freqs:
            for j, m in enumerate(("A", "B", "C")):
                x = np.full(3, -1.0 - ((i + j) % 3))
                _add(rows, pw, _ok_row(ds, m, f, 0, x), x)
    result = _result(study, rows, pw)
    fig = best_model_figure(result)
    fig.canvas.draw()
    (ax,) = fig.axes
    box = ax.get_window_extent().transformed(fig.dpi_scale_trans.inverted())
    assert box.width / 10 >= 0.9 and box.height / 20 >= 0.2  # inches per cell
    assert len(ax.texts) == 200
    assert all(t.get_fontsize() >= 5.5 for t in ax.texts)
    # legend and labels outside the grid: nothing drawn over the cells
    legend = fig.legends[0].get_window_extent().transformed(fig.dpi_scale_trans.inverted())
    assert legend.x0 >= box.x1
    scores = scores_vs_frequency_figure(result)
    assert all(ax.get_xscale() == "log" for ax in scores.axes)  # 0.5 … 500 Hz
    assert len([ln for ln in scores.axes[0].lines if ln.get_gid()]) == 60
