"""The command line, end to end: output, JSON, exit status on bad input, and what a
failed run leaves in its output folder."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

import bayeshyst.diagnosis
import bayeshyst.diagnostics
import bayeshyst.inference.fit
import bayeshyst.outputs
import bayeshyst.selection
import bayeshyst.study
import bayeshyst.workflow
from bayeshyst import models
from bayeshyst.cli import build_parser, main
from bayeshyst.errors import ParameterError

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "data" / "virtual_multifreq.csv"
# the module (bayeshyst.inverse.compensate is also the name of its function)
COMPENSATE = importlib.import_module("bayeshyst.inverse.compensate")


def test_models_lists_every_registered_model_with_parameters(capsys):
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    for name in models.names():
        assert f"\n{name}  [" in "\n" + out
    assert "Normal(mu=" in out and "fixed = " in out


def test_models_json_matches_param_spaces(capsys):
    assert main(["models", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    by_name = {m["name"]: m for m in doc["models"]}
    assert sorted(by_name) == models.names()
    for name, entry in by_name.items():
        space = models.get(name).param_space()
        assert [p["name"] for p in entry["parameters"]] == list(space.all_names)
        for p in entry["parameters"]:
            assert p["unit"] is not None and p["description"]


def test_models_lists_the_gp_models_and_every_effect_block(capsys):
    from bayeshyst.gp import gp_names
    from bayeshyst.models.blocks import block_class, block_names

    assert main(["models", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [g["name"] for g in doc["gaussian_processes"]] == gp_names() == ["gp", "gp_memory"]
    assert [b["name"] for b in doc["effect_blocks"]] == block_names()
    for entry in doc["effect_blocks"]:
        cls = block_class(entry["name"])
        space = cls(**cls.example).param_space()
        assert [p["name"] for p in entry["parameters"]] == list(space.all_names)
    assert main(["models", "gp_memory", "creep"]) == 0  # any of them by name
    out = capsys.readouterr().out
    assert "gp_memory  [GPHysteresis" in out and "creep  [Creep" in out


@pytest.mark.parametrize("command", ["fit", "compare", "compensate", "diagnose", "report"])
def test_an_unknown_likelihood_is_refused_with_the_valid_names(command, tmp_path):
    res = subprocess.run([sys.executable, "-m", "bayeshyst.cli", command, str(DATA),
                          "--model" if command in ("fit", "compensate", "diagnose")
                          else "--models", "pi_play", "--likelihood", "cauchy",
                          "--out", str(tmp_path / "out")], capture_output=True, text=True)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "invalid choice: 'cauchy' (choose from 'ar1', 'gaussian', 'student_t')" in res.stderr
    assert not (tmp_path / "out").exists()


def test_every_command_shows_an_example_and_verbose_logs_the_library(tmp_path):
    from bayeshyst.cli.parser import EXAMPLES

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert set(commands) == set(EXAMPLES)
    for name, sub in commands.items():
        text = sub.format_help()
        assert "example:\n  bayeshyst " + name in text, name
    res = subprocess.run([sys.executable, "-m", "bayeshyst.cli", "fit", str(DATA), "--model",
                          "pi_play(n_operators=2)", "--steps", "300", "--no-figures",
                          "--no-calibration", "--quiet", "-v", "--out", str(tmp_path / "f")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr[-500:]
    assert "bayeshyst.data.io: " in res.stderr and "bayeshyst.inference.fit: fitting" in res.stderr
    assert "bayeshyst.inference.sampling" not in res.stderr  # its step records are -vv


def test_unknown_model_exits_2_with_one_line_and_no_traceback():
    res = subprocess.run([sys.executable, "-m", "bayeshyst.cli", "models", "pi_plya"],
                         capture_output=True, text=True)
    assert res.returncode == 2
    assert res.stdout == ""
    assert res.stderr.strip().count("\n") == 0
    assert "unknown model(s) ['pi_plya']" in res.stderr and "Traceback" not in res.stderr


def test_usage_error_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fly"])
    assert exc.value.code == 2


# ------------------------------------------------------- a failed run and its --out
# Every command that samples, with the library call that does its long part replaced
# by one that writes what the real one writes before its first result (a checkpoint)
# and then fails as the real one can ("could not place walkers"). ``result`` makes the
# fake produce the command's first result before failing instead.
def _fake(out: Path, result: str | None):
    def run(*args, **kwargs):
        (out / "checkpoints").mkdir(parents=True, exist_ok=True)
        (out / "checkpoints" / "fit.h5").write_bytes(b"chains")
        if result == "on_fit":
            kwargs["on_fit"](SimpleNamespace())  # --quiet: the callback only counts it
        elif result is not None:
            (out / result).parent.mkdir(parents=True, exist_ok=True)
            (out / result).write_bytes(b"a finished fit")
        raise ParameterError("could not place 52 walkers with finite density around the MAP")
    return run


COMMANDS = {
    # command: (arguments, function replaced, what its first result is)
    "fit": (["fit", str(DATA), "--model", "pi_play"],
            (bayeshyst.inference.fit, "fit_model"), None),
    "compensate": (["compensate", str(DATA), "--model", "pi_play"],
                   (bayeshyst.inference.fit, "fit_model"), None),
    "compare": (["compare", str(DATA), "--models", "pi_play"],
                (bayeshyst.selection, "compare_models"), "posteriors/pi_play@1Hz.nc"),
    "diagnose": (["diagnose", str(DATA), "--model", "pi_play"],
                 (bayeshyst.diagnosis, "diagnose"), "on_fit"),
    "report": (["report", str(DATA), "--models", "pi_play"],
               (bayeshyst.workflow, "run_report"), "on_fit"),
    "demo": (["demo", "--quick"], (bayeshyst.workflow, "run_report"), "on_fit"),
    "study": (["study", "STUDY"], (bayeshyst.study, "run_study"), "fits/0a1b2c.json"),
}


def _args(command: str, out: Path, tmp_path: Path) -> list[str]:
    study = tmp_path / "s.toml"
    study.write_text(f'name = "s"\nmodels = ["pi_play"]\n[[datasets]]\npath = "{DATA}"\n')
    args = [str(study) if a == "STUDY" else a for a in COMMANDS[command][0]]
    return [*args, "--out", str(out), "--quiet"]


def _tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_failure_before_the_first_result_leaves_out_as_it_was(command, tmp_path, monkeypatch,
                                                              capsys):
    _, (module, name), _ = COMMANDS[command]
    new = tmp_path / "new" / "out"  # neither exists yet
    monkeypatch.setattr(module, name, _fake(new, None))
    assert main(_args(command, new, tmp_path)) == 2
    assert "could not place 52 walkers" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()

    old = tmp_path / "old"  # a user's folder, and a checkpoint of an earlier run
    (old / "checkpoints").mkdir(parents=True)
    (old / "notes.txt").write_text("mine")
    (old / "checkpoints" / "fit.h5").write_bytes(b"earlier")
    monkeypatch.setattr(module, name, _fake(old, None))
    assert main(_args(command, old, tmp_path)) == 2
    assert _tree(old) == ["checkpoints", "checkpoints/fit.h5", "notes.txt"]
    assert (old / "notes.txt").read_text() == "mine"
    assert (old / "checkpoints" / "fit.h5").read_bytes() == b"chains"  # resumed, kept


@pytest.mark.parametrize("command", sorted(c for c, v in COMMANDS.items() if v[2]))
def test_failure_after_the_first_result_keeps_what_a_rerun_resumes_from(command, tmp_path,
                                                                       monkeypatch):
    _, (module, name), result = COMMANDS[command]
    out = tmp_path / "out"
    monkeypatch.setattr(module, name, _fake(out, result))
    assert main(_args(command, out, tmp_path)) == 2
    assert "checkpoints/fit.h5" in _tree(out)


@pytest.mark.parametrize("command", ["fit", "compensate"])
def test_a_finished_fit_is_a_result_even_if_what_follows_fails(command, tmp_path,
                                                               monkeypatch):
    # the fit returns (its chains are in the checkpoint); what follows fails: building
    # the outputs (the InferenceData comes first), writing them, or designing
    out = tmp_path / "out"

    def fit_model(*args, sampler, **kwargs):
        sampler.checkpoint.parent.mkdir(parents=True)
        sampler.checkpoint.write_bytes(b"chains")
        return SimpleNamespace(posterior=None, sampling=None)

    def broken(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(bayeshyst.inference.fit, "fit_model", fit_model)
    monkeypatch.setattr(bayeshyst.diagnostics, "to_inference_data", broken)
    monkeypatch.setattr(bayeshyst.outputs, "write_fit_outputs", broken)
    monkeypatch.setattr(COMPENSATE, "compensate", broken)
    with pytest.raises(RuntimeError, match="disk full"):  # an internal error: exit 1
        main(_args(command, out, tmp_path))
    assert _tree(out) == ["checkpoint.h5"]
