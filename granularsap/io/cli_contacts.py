"""Alias of :mod:`granularsap.cli.contacts`, for one release.

The command line of ``granularsap contacts`` (its arguments and ``run``) moved
to :mod:`granularsap.cli.contacts`; what it runs is
:func:`granularsap.io.compute_contacts`.  Import from there; this module will
be removed in the next release.
"""

from __future__ import annotations

from ..cli.contacts import add_arguments, run

__all__ = ["add_arguments", "run"]
