"""Alias of :mod:`granularsap.boxes` (the box engine), for one release.

``granularsap.api`` is the same module object as ``granularsap.boxes``, so that
code which imports it, or sets its module constants, keeps working.
"""

import sys

from . import boxes

sys.modules[__name__] = boxes
