"""``python -m hdrd`` is the ``hdrd`` command."""

import sys

from hdrd.cli import main

sys.exit(main())
