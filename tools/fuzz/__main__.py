"""``python -m tools.fuzz``: the harness's command line (tools/fuzz/harness.py)."""

import sys

from .harness import main

sys.exit(main())
