"""Alias of :mod:`granularsap.cli.validate` and :mod:`granularsap.compare`, for one release.

The comparison ``granularsap validate`` runs moved to :mod:`granularsap.compare`
(:func:`~granularsap.compare.compare_trajectory`), its command line (arguments
and ``run``) to :mod:`granularsap.cli.validate`; the new names also keep this
module apart from :mod:`granularsap._validate` (the engine's argument checks).
Import from there; this module will be removed in the next release.
"""

from __future__ import annotations

from .cli.validate import add_arguments, run
from .compare import DEFAULT_CUTOFF, REFERENCES, compare_trajectory

__all__ = ["DEFAULT_CUTOFF", "REFERENCES", "add_arguments", "compare_trajectory", "run"]
