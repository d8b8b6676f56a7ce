"""``python -m granularsap.cli``: the same as ``granularsap`` and ``python -m granularsap``."""

import sys

from . import main

sys.exit(main())
