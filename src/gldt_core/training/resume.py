"""Reading a training checkpoint to continue from, for the detectors and the second stage alike.

A training run may outlast a working day (issue #28): it writes ``last.pt`` after every epoch
with everything needed to go on (weights, optimiser, schedule, epoch, time spent), and
``--resume last.pt`` continues it on any machine. A checkpoint that cannot be continued gives one
line naming what was wrong, before anything is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch


class ResumeError(ValueError):
    """A checkpoint that cannot be resumed from (missing, unreadable, or for another config)."""


def read_checkpoint(path: Path | str, action: str = "resume") -> dict[str, Any]:
    """The mapping saved at ``path``; :class:`ResumeError` ("cannot ``action``: ...") when it is
    missing or not a checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise ResumeError(f"cannot {action}: checkpoint not found: {path}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # a truncated or foreign file: torch raises several kinds
        raise ResumeError(
            f"cannot {action}: {path} is not a readable checkpoint ({type(error).__name__}: {error})"
        ) from None
    if not isinstance(checkpoint, dict):
        raise ResumeError(f"cannot {action}: {path} holds a {type(checkpoint).__name__}, not a training checkpoint")
    return checkpoint


def add_seconds(spent: dict[str, float], device: str, seconds: float) -> dict[str, float]:
    """``spent`` (training seconds by device type) with ``seconds`` more on ``device``."""
    out = dict(spent)
    out[device] = round(out.get(device, 0.0) + seconds, 1)
    return out
