"""The command line's own error: a leaf module that imports nothing of granularsap.

A subcommand raises :class:`CLIError` for a wrong input it found itself; the
library below raises ``ValueError``, ``OSError`` and the like, which
:func:`granularsap.cli.main` reports the same way (one line, exit code 2).
"""

from __future__ import annotations

__all__ = ["CLIError"]


class CLIError(Exception):
    """An error reported to the user as one line, exit code 2."""
