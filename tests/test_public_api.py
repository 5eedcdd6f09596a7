"""The public names: every one in ``__all__`` resolves, to the object its module
defines, and every registered model family's class is importable from
``bayeshyst.models``."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import bayeshyst
from bayeshyst import inference, models


@pytest.mark.parametrize("package", [bayeshyst, inference, models])
def test_every_public_name_resolves(package):
    for name in package.__all__:
        assert getattr(package, name) is not None, name
        assert name in dir(package)
    with pytest.raises(AttributeError, match="no attribute"):
        package.no_such_name  # noqa: B018


def test_lazy_names_are_the_defining_modules_objects():
    for name, (module, attribute) in bayeshyst._LAZY.items():
        assert getattr(bayeshyst, name) is getattr(importlib.import_module(module), attribute)
    for name, sub in inference._EXPORTS.items():
        assert getattr(inference, name) is getattr(
            importlib.import_module(f"bayeshyst.inference.{sub}"), name)


def test_every_registered_model_class_is_exported():
    exported = {getattr(models, n) for n in models.__all__ if isinstance(getattr(models, n), type)}
    for name in models.names():
        assert models.model_class(name) in exported, name


def test_the_verbs_take_data_first_then_model():
    """The verbs a user types in the CLI, with one argument order."""
    import inspect

    for verb in ("fit", "compare", "diagnose", "compensate", "report"):
        params = list(inspect.signature(getattr(bayeshyst, verb)).parameters)
        assert params[0] == "data", verb
        assert params[1] in ("model", "models"), verb
    post = list(inspect.signature(bayeshyst.Posterior).parameters)
    assert post[:2] == ["data", "model"]


def test_posterior_in_the_old_order_is_refused_in_words():
    """Posterior(model, data) was the order before; it is refused, never swapped."""
    from bayeshyst.data import Record
    from bayeshyst.errors import ParameterError

    t = np.arange(200) / 1000.0
    rec = Record(t=t, u=50 + 50 * np.sin(2 * np.pi * 5 * t), y=np.sin(2 * np.pi * 5 * t),
                 name="r")
    with pytest.raises(ParameterError, match="data come first"):
        bayeshyst.Posterior("bouc_wen", rec)
    assert bayeshyst.Posterior(rec, "bouc_wen").model.name == "bouc_wen"


def test_the_readme_model_table_lists_every_model_with_its_review_reference():
    # oracle: the registry -- every registered model is a row whose "review ref" is the
    # model's own equation attribute, so the table cannot drift from the code
    import re
    from pathlib import Path

    import bayeshyst.models as M

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    found = re.findall(r"^\| `([a-z_]+)` \| [^|]+ \| ([^|]+) \| (yes|no) \|$", text,
                       re.MULTILINE)
    assert sorted(name for name, _, _ in found) == sorted(M.names())
    for name, ref, rate in found:
        model = M.get(name)
        assert ref.strip() == model.equation, name
        assert ref.strip().startswith("review Eq.")
        assert (rate == "yes") == model.rate_dependent, name
