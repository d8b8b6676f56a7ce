"""Alias of :mod:`granularsap.mda.analysis`, for one release.

``granularsap.mda_analysis`` is the same module object as ``granularsap.mda.analysis``.
"""

import sys

from .mda import analysis

sys.modules[__name__] = analysis
