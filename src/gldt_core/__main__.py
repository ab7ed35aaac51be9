"""``python -m gldt_core`` is the same as the ``gldt`` command."""

import sys

from gldt_core.cli import main

sys.exit(main())
