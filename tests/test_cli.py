"""The command line, end to end: output, JSON, exit status on bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from bayeshyst import models
from bayeshyst.cli import main


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
