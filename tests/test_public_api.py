"""The public names: every one in ``__all__`` resolves, to the object its module
defines, and every registered model family's class is importable from
``bayeshyst.models``."""

from __future__ import annotations

import importlib

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
    for name, module in bayeshyst._LAZY.items():
        assert getattr(bayeshyst, name) is getattr(importlib.import_module(module), name)
    for name, sub in inference._EXPORTS.items():
        assert getattr(inference, name) is getattr(
            importlib.import_module(f"bayeshyst.inference.{sub}"), name)


def test_every_registered_model_class_is_exported():
    exported = {getattr(models, n) for n in models.__all__ if isinstance(getattr(models, n), type)}
    for name in models.names():
        assert models.model_class(name) in exported, name
