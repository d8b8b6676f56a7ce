"""Alias of :mod:`granularsap.mda.fastns`, for one release.

``granularsap.mda_fastns`` is the same module object as ``granularsap.mda.fastns``.
"""

import sys

from .mda import fastns

sys.modules[__name__] = fastns
