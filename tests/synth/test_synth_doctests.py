"""The docstring examples of the pure `synth` modules run as written."""

from __future__ import annotations

import doctest
import importlib

import pytest

DOCTEST_MODULES = ("synth.cable", "synth.hand", "synth.person", "synth.config_fields",
                   "synth.contact_sheet", "synth.realism", "synth.exposure")


@pytest.mark.parametrize("module", DOCTEST_MODULES)
def test_docstring_examples(module: str) -> None:
    failed, tried = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert failed == 0
    assert tried > 0
