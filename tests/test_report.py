"""The study report: ``bayeshyst demo --quick`` end to end, the HTML parsed, escaping.

Oracles: the bundled CSV read independently (frequencies, records), the PNG files the
run wrote (each must be embedded byte for byte), the numbers of ``summary.json`` (each
table cell must show them), and the HTML parser itself (a ``<script>`` in the data
must not become a tag).
"""

from __future__ import annotations

import base64
import csv
import json
import math
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from bayeshyst.cli import main
from bayeshyst.data import load
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.writers import write_csv
from bayeshyst.demo import DEMO_QUICK, bundled_data
from bayeshyst.outputs import html as H
from bayeshyst.outputs.report_outputs import SECTIONS

EVIL = '<script>alert("x")</script>'


class _Page(HTMLParser):
    """Collects what a browser would see: tags, image sources, table cells, text."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: dict[str, int] = {}
        self.images: list[str] = []
        self.links: list[str] = []
        self.section_ids: list[str] = []
        self.cells: list[str] = []
        self.text: list[str] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags[tag] = self.tags.get(tag, 0) + 1
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src") or "")
        if tag in ("a", "link", "script", "iframe") and (a.get("href") or a.get("src")):
            self.links.append(a.get("href") or a.get("src") or "")
        if tag == "section":
            self.section_ids.append(a.get("id") or "")
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data: str) -> None:
        self.text.append(data)
        if self._cell is not None:
            self._cell.append(data)


def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8"))
    page.close()
    return page


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, Path]:
    out = tmp_path_factory.mktemp("demo")
    code = main(["demo", "--quick", "--out", str(out), "--quiet"])
    return code, out


def _bundled_frequencies() -> list[float]:
    """Frequencies of the bundled data, read from the CSV and sidecar without bayeshyst."""
    path = bundled_data()
    side = json.loads(path.with_suffix(".json").read_text())
    with path.open() as fh:
        n_records = len({row["record"] for row in csv.DictReader(fh)})
    freqs = [float(r["metadata"]["frequency_hz"]) for r in side["records"]]
    assert len(freqs) == n_records
    return sorted(freqs)


def test_demo_summary_has_every_section(demo: tuple[int, Path]) -> None:
    code, out = demo
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    # the quick demo runs a subset of the bundled frequencies
    freqs = sorted(DEMO_QUICK.frequencies_hz)
    assert set(freqs) <= set(_bundled_frequencies())
    for name in SECTIONS:
        assert summary.get(name), f"section {name} missing or empty"
    assert summary["command"] == "report"
    assert summary["data"]["frequencies_hz"] == freqs
    assert summary["data"]["n_records"] == len(freqs)
    sel = summary["model_selection"]
    assert sel["models"] == list(DEMO_QUICK.models)
    assert [fc["frequency_hz"] for fc in sel["per_frequency"]] == freqs
    # the best at each frequency is the model with the highest elpd there
    for fc in sel["per_frequency"]:
        ok = [s for s in fc["ranking"] if s["error"] is None]
        assert fc["best"] == max(ok, key=lambda s: s["elpd_loo"])["model"]
    # the diagnosed model is the best parametric model jointly
    assert summary["chosen_model"] == sel["overall"]["best"]
    dg = summary["diagnosis"]
    assert dg["base_model"].startswith(summary["chosen_model"])
    assert [p["frequency_hz"] for p in dg["per_frequency"]] == freqs
    comp = summary["compensation"]
    assert [r["frequency_hz"] for r in comp["per_frequency"]] == freqs
    assert comp["plant_kind"] == "virtual actuator"
    # the uncertainty analysis: the final model's budget and its calibration check per
    # frequency; the shares are the three variances over their sum, the sd its root
    unc = summary["uncertainty"]
    assert unc["checked"] and [r["frequency_hz"] for r in unc["per_frequency"]] == freqs
    for r in unc["per_frequency"]:
        parts = (r["noise_var"], r["parameter_var"], r["discrepancy_var"])
        assert r["predictive_sd"] == pytest.approx(sum(parts) ** 0.5, rel=1e-9)
        assert sum(r["shares"].values()) == pytest.approx(1.0)
        assert r["dominant"] == max(r["shares"], key=r["shares"].get)
        c = r["calibration"]
        assert c["frequency_hz"] == r["frequency_hz"] and 0 <= c["coverage_90"] <= 1
        assert c["calibrated"] is (c["expected_50"][0] <= c["coverage_50"] <= c["expected_50"][1]
                                   and c["expected_90"][0] <= c["coverage_90"]
                                   <= c["expected_90"][1])
    assert [r["frequency_hz"] for r in unc["tracking_band"]] == freqs
    # the model-averaged design: per frequency, the comparison's models of weight >= 1 %
    # (all parametric in the quick demo), at their stacking weights renormalised
    avg = summary["model_averaged_feedforward"]
    assert [r["frequency_hz"] for r in avg["per_frequency"]] == freqs
    for r, fc in zip(avg["per_frequency"], sel["per_frequency"], strict=True):
        kept = {s["model"]: s["weight"] for s in fc["ranking"]
                if s["error"] is None and s["weight"] >= 0.01}
        assert sorted(r["models"]) == sorted(kept)
        total = sum(kept.values())
        for m, w in zip(r["models"], r["weights"], strict=True):
            assert w == pytest.approx(kept[m] / total, rel=1e-9)
        assert sum(r["design_draws"]) == max(DEMO_QUICK.settings.design_draws, len(kept))
        assert r["single_model"] == max(kept, key=kept.get)
        lo, hi = r["predicted_band_percent"]
        assert 0 <= lo <= hi and r["realised_inside_band"] is (
            lo <= r["averaged_nrmse_percent"] <= hi)
        if len(kept) == 1:  # a one-model average is that model's own design
            assert r["single_nrmse_percent"] == r["averaged_nrmse_percent"]
    # every fit's posterior is on disk as netCDF
    for f in sel["fits"]:
        assert (out / "compare" / "posteriors" / Path(f["posterior"]).name).is_file()
    assert (out / "diagnose" / "posterior_base.nc").is_file()
    assert (out / "compensate" / comp["files"]["posterior"]).resolve().is_file()
    # the summary warns of non-convergence exactly when a fit did not converge; the
    # quick demo is sized so that every fit converges (issue 17: 6 of 6 on 2 cores)
    unconverged = [f["key"] for f in sel["fits"] if not f["converged"]]
    if not summary["posteriors"]["base_converged"]:
        unconverged.append("diagnosis base")
    warned = any("not converge" in w.lower() for w in summary["warnings"])
    assert warned is bool(unconverged)
    assert not unconverged, f"fits that did not converge: {unconverged}"
    # a calibration warning is the final model's (the diagnosed one, not the chosen)
    for w in summary["warnings"]:
        if "(final model)" in w:
            assert w.startswith(f"{dg['final_model']} (final model): "), w


def test_report_html_embeds_every_figure_and_needs_no_network(demo: tuple[int, Path]) -> None:
    _, out = demo
    page = _parse(out / "report.html")
    embedded = set()
    for src in page.images:
        assert src.startswith("data:image/png;base64,"), src[:60]
        data = base64.b64decode(src.split(",", 1)[1])
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
        embedded.add(data)
    must = [*sorted((out / "figures").glob("*.png")), out / "compare" / "compare.png",
            out / "diagnose" / "residuals.png", out / "compensate" / "compensate.png"]
    for png in must:
        assert png.read_bytes() in embedded, f"{png.relative_to(out)} not embedded"
    # and nothing else: every embedded image is a file the run wrote
    written = {p.read_bytes() for p in out.rglob("*.png")}
    assert embedded <= written
    assert all(link.startswith("#") for link in page.links), page.links
    assert page.tags.get("script", 0) == 0
    assert page.section_ids == ["glance", "data", "posteriors", "model-selection",
                                "diagnosis", "uncertainty", "compensation", "reproduce"]


def test_report_tables_have_no_nan_and_show_the_summary_numbers(
        demo: tuple[int, Path]) -> None:
    _, out = demo
    page = _parse(out / "report.html")
    assert page.cells
    bad = [c for c in page.cells if re.search(r"\b(nan|inf)\b", c, re.IGNORECASE)]
    assert not bad, bad[:5]
    summary = json.loads((out / "summary.json").read_text())
    # each model's elpd at each frequency appears, formatted as the table formats it
    for fc in summary["model_selection"]["per_frequency"]:
        for s in fc["ranking"]:
            if s["elpd_loo"] is not None:
                assert f"{s['elpd_loo']:.1f}" in page.cells
    for r in summary["compensation"]["per_frequency"]:
        assert format(r["robust_nrmse_percent"], ".4g") in page.cells


def test_metadata_with_script_comes_out_escaped(tmp_path: Path, capsys) -> None:
    one = load(bundled_data()).by_frequency()[50.0][0]
    rec = one.with_(name=f"run {EVIL}",
                    metadata={**one.metadata, "operator": EVIL, "note": "a & b"})
    data_file = tmp_path / "evil<b>.csv"
    write_csv(Dataset((rec,), name=f"bench {EVIL}"), data_file)
    out = tmp_path / "out"
    # (the data file doubles as --validation: the feedforward bands then say where their
    # residual came from -- one run instead of two)
    # a fast model and no calibration: what is checked is the writing, not the fit
    code = main(["report", str(data_file), "--models", "pi_play(n_operators=3)",
                 "--steps", "100", "--no-lofo", "--max-refits", "0", "--max-rounds", "1",
                 "--no-calibration", "--no-figures", "--quiet", "--json",
                 "--validation", str(data_file), "--out", str(out)])
    assert code == 0
    # --json prints summary.json as written (same serialiser), byte for byte
    assert capsys.readouterr().out == (out / "summary.json").read_text()
    raw = (out / "report.html").read_text(encoding="utf-8")
    page = _parse(out / "report.html")
    assert page.tags.get("script", 0) == 0 and page.tags.get("b", 0) == 0
    assert "&lt;script&gt;" in raw
    text = "".join(page.text)
    assert f"run {EVIL}" in text and f"bench {EVIL}" in text and "evil<b>.csv" in text
    assert "a & b" in text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["compensation"]["settings"]["residual_from"] == (
        f"validation records: {rec.name}")


def test_report_samples_the_base_models_joint_posterior_once(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The diagnosis' base fit is the comparison's joint fit of the chosen model (same
    posterior, same sampler settings, same checkpoint folder): it is read back from the
    comparison's checkpoint, not sampled a second time."""
    import emcee

    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.selection.tasks import fit_sampler
    from bayeshyst.workflow import ReportSettings, run_report

    fresh: list[tuple[str, int, str]] = []  # (model, records, held out) per new ensemble
    real = emcee.EnsembleSampler.sample

    def spy(self: emcee.EnsembleSampler, *args: object, **kwargs: object):
        if self.iteration == 0:
            post = self.log_prob_fn.f.__self__
            fresh.append((post.model.name, len(post.data), str(post.held_out)))
        yield from real(self, *args, **kwargs)

    monkeypatch.setattr(emcee.EnsembleSampler, "sample", spy)
    data = load(bundled_data()).select([1.0, 50.0])
    model = "pi_play(n_operators=4)"
    sampler = SamplerSettings(max_steps=100, first_chunk=50, seed=4)
    # 100 steps do not converge; sampled again with 200 (budget_doublings, tested in
    # test_diagnosis_budget.py) a fit is no longer the comparison's: here it must be read back
    settings = ReportSettings(sampler=sampler, lofo=False, max_refits=0, max_rounds=1,
                              max_candidates=1, effects=("rate_dependence",),
                              design_draws=8, n_jobs=1, budget_doublings=0)
    out = tmp_path / "out"
    result = run_report(data, (model,), settings=settings, out_dir=out)
    assert result.chosen_model == model and result.seed == 4
    base = Posterior(data, model, "gaussian")
    # the joint posterior of the base model: one run of n_ensembles ensembles, in total
    joint = [f for f in fresh if f[1] == len(data) and f[0] == base.model.name
             and f[2] == str(base.held_out)]
    assert len(joint) == sampler.n_ensembles, fresh
    assert result.diagnosis.base.sampling.chains.shape[0] == sampler.n_ensembles
    # one checkpoint per distinct fit, all in the comparison's folder: the comparison's
    # joint and per-frequency fits, and the diagnosis' augmented fits (not its base fit)
    folder = out / "compare" / "checkpoints"
    files = sorted(folder.glob("*.h5"))
    n_compare = 1 + len(data.frequencies)
    assert len(files) == n_compare + len(result.diagnosis.steps)
    assert fit_sampler(base, sampler, sampler.seed, folder).checkpoint in files
    assert not (out / "diagnose" / "checkpoints").exists()


def test_report_bad_input_exits_2_and_writes_nothing(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "out"
    assert main(["report", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
    assert "missing.csv" in capsys.readouterr().err
    assert main(["report", str(bundled_data()), "--models", "bouc_wen,no_such_model",
                 "--out", str(out)]) == 2
    assert "no_such_model" in capsys.readouterr().err
    assert main(["report", str(bundled_data()), "--validation", str(tmp_path / "gone.csv"),
                 "--out", str(out)]) == 2
    assert "gone.csv" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------ the HTML builder
def test_html_builder_escapes_text_and_hides_missing_numbers() -> None:
    t = H.table(["a", "b"], [[EVIL, math.nan], ["x", None], ["y", 1.5]])
    page = _Page()
    page.feed(t)
    assert page.tags.get("script", 0) == 0
    assert page.cells == ["a", "b", EVIL, H.MISSING, "x", H.MISSING, "y", "1.5"]
    assert H.number(math.inf) == H.MISSING and H.number(float("nan")) == H.MISSING
    assert H.text(H.Markup("<b>ok</b>")) == "<b>ok</b>"  # built markup passes through
    with pytest.raises(ValueError, match="row 0 has 1 cells"):
        H.table(["a", "b"], [["only one"]])
    with pytest.raises(ValueError, match="not a PNG"):
        H.figure(b"GIF89a", "x")


CHROMIUM = next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser",
                                                       "google-chrome")) if p), None)


@pytest.mark.skipif(CHROMIUM is None, reason="no headless Chromium on this machine (Debian: "
                                             "apt install chromium)")
def test_report_renders_in_a_real_browser_without_errors(demo: tuple[int, Path],
                                                         tmp_path: Path) -> None:
    # a wrapper page loads the report in a frame and counts the images the browser
    # decoded (naturalWidth > 0): a broken image is one the browser could not show
    _, out = demo
    report = (out / "report.html").resolve()
    wrapper = tmp_path / "wrapper.html"
    wrapper.write_text(
        f'<html><body><iframe id="f" src="{report.as_uri()}" style="width:1200px;'
        'height:800px"></iframe><pre id="out">pending</pre><script>'
        "document.getElementById('f').onload = function () {"
        " var imgs = this.contentDocument.images, bad = [];"
        " for (var i = 0; i < imgs.length; i++) {"
        "  if (!(imgs[i].complete && imgs[i].naturalWidth > 0)) bad.push(imgs[i].alt || i); }"
        " document.getElementById('out').textContent ="
        "  'images ' + imgs.length + ' broken ' + JSON.stringify(bad); };"
        "</script></body></html>")
    common = [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu",
              "--allow-file-access-from-files", "--enable-logging=stderr", "--v=0"]
    run = subprocess.run([*common, "--virtual-time-budget=15000", "--dump-dom",
                          wrapper.as_uri()], capture_output=True, text=True, timeout=180)
    found = re.search(r"images (\d+) broken (\[[^<]*\])", run.stdout)
    assert found, run.stdout[-500:] + run.stderr[-2000:]
    n_img, broken = int(found.group(1)), json.loads(found.group(2))
    html_imgs = (out / "report.html").read_text().count("<img ")
    assert n_img == html_imgs > 0 and broken == []
    console = [ln for ln in run.stderr.splitlines()
               if "CONSOLE" in ln or "Uncaught" in ln or "Failed to load resource" in ln]
    assert console == []
    shot = tmp_path / "report.png"
    subprocess.run([*common, f"--screenshot={shot}", "--window-size=1280,6000",
                    report.as_uri()], capture_output=True, timeout=180)
    assert shot.is_file() and shot.stat().st_size > 50_000  # a page, not a blank


def test_the_calibration_check_in_a_worker_gives_the_in_process_numbers(tmp_path: Path) -> None:
    """With more than one process the calibration check runs in a worker of its own
    while the feedforward is designed; oracle: the same report run in one process, same
    seed (a worker's serial kernels give the bits of the parallel ones)."""
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.workflow import ReportSettings, run_report

    data = load(bundled_data()).select([50.0])
    runs = {}
    for jobs in (1, 2):
        settings = ReportSettings(sampler=SamplerSettings(max_steps=600, seed=3), lofo=False,
                                  max_refits=0, max_rounds=1, max_candidates=1,
                                  effects=("asymmetry",), design_draws=8, n_jobs=jobs,
                                  averaged=False)
        runs[jobs] = run_report(data, ("pi_play(n_operators=2)",), settings=settings,
                                out_dir=tmp_path / f"jobs{jobs}")
    one, two = runs[1], runs[2]
    assert one.calibration is not None and one.calibration.per_frequency
    assert two.calibration.to_dict() == one.calibration.to_dict()
    assert two.compensation.to_dict() == one.compensation.to_dict()
    assert list(two.runtime_s) == ["compare", "diagnose", "calibrate", "compensate", "total"]
