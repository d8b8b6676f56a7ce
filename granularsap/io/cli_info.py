"""Alias of :mod:`granularsap.cli.info` and :mod:`granularsap.io.summary`, for one release.

The command line of ``granularsap info`` (its arguments and ``run``) moved to
:mod:`granularsap.cli.info`, :func:`summarize` and :func:`plot` to
:mod:`granularsap.io.summary`.  Import from there; this module will be removed
in the next release.
"""

from __future__ import annotations

from ..cli.info import add_arguments, run
from .summary import plot, summarize

__all__ = ["add_arguments", "plot", "run", "summarize"]
