"""Alias of :mod:`granularsap.ase.neighborlist`, for one release.

``granularsap.ase_neighborlist`` is the same module object as ``granularsap.ase.neighborlist``.
"""

import sys

from .ase import neighborlist

sys.modules[__name__] = neighborlist
