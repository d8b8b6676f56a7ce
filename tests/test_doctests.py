"""The examples in the public docstrings run as written."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ["granularsap.search", "granularsap.particles", "granularsap.api", "granularsap.cell",
           "granularsap.inputs", "granularsap.periodic", "granularsap.mda", "granularsap.ase",
           "granularsap.ase_neighborlist", "granularsap.mda_fastns", "granularsap._memory",
           "granularsap.io._lock", "granularsap.cli.argtypes", "granularsap.geometry",
           "granularsap.sweep_candidates", "granularsap.search.plan", "granularsap.compare"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
    if name in ("granularsap.search", "granularsap.particles", "granularsap.api"):
        assert result.attempted > 0
