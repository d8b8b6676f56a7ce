"""Alias of :mod:`granularsap.mda.arith`, for one release.

``granularsap._mda_arith`` is the same module object as ``granularsap.mda.arith``.
"""

import sys

from .mda import arith

sys.modules[__name__] = arith
