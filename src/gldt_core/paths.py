"""Where the optional real-clip data lives, without hard-coding one machine's layout.

The Halmstad clips sit in ``shared/data/halmstad-visible`` beside the repository checkout
(``../shared``); ``$GLDT_HALMSTAD`` overrides that. Nothing at run time requires them: tests and
benchmarks that use them skip or say so when the folder is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]


def halmstad_root() -> Path:
    """The Halmstad visible-clips folder (``videos/``, ``gt/``); may not exist."""
    override = os.environ.get("GLDT_HALMSTAD")
    if override:
        return Path(override)
    return REPO_ROOT.parent / "shared" / "data" / "halmstad-visible"
