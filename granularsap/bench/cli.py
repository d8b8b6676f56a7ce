"""Alias of :mod:`granularsap.cli.bench` and :mod:`granularsap.bench.runner`, for one release.

The command line of ``granularsap bench`` moved to :mod:`granularsap.cli.bench`
(its arguments and ``run``), the run of the workloads to
:mod:`granularsap.bench.runner` (:func:`~granularsap.bench.runner.execute`) and
:func:`parse_size` to :mod:`granularsap.cli.argtypes`.  Import them from there;
this module will be removed in the next release.
"""

from __future__ import annotations

from ..cli.argtypes import parse_size
from ..cli.bench import add_arguments, run
from .runner import PREDICT_FACTOR, PROGRESS_EVERY, execute, list_peers

__all__ = ["PREDICT_FACTOR", "PROGRESS_EVERY", "add_arguments", "execute", "list_peers",
           "parse_size", "run"]
