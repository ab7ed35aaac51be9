"""Track birth from persistent low-score detections (an M-of-M confirmation, as radar trackers do).

ByteTrack-style trackers start a track only from a detection scored ``>= new_track_thresh``;
low-score boxes may only extend tracks that exist. That assumes a detector confident on its true
targets. The small detectors shipped here are not always: on some held-out Halmstad clips AM-YOLO
finds the drone in almost every frame but scores it below the new-track threshold, the tracker
starts no track, and the GL-DT schedule keeps searching with the global detector all that time.
Clutter rarely comes back at the same place frame after frame; a small target does (and, as it
turned out, so does a bird).

:class:`LowScoreBirth` keeps *candidates*: chains of unclaimed low-score detections, one per
frame, each within a distance gate of the one before. A chain that reaches ``frames`` links
gives a new track; a chain that misses a frame is dropped. It only sees what the association
stages left over, so it never competes with a live track for a detection.

Off by default (``low_score_birth_frames: 0``): the trackers and the GL-DT system keep ByteTrack's
birth rule. With the shipped detectors it shortened the global detector's search but cost MOTA
and multiplied the false drone tracks on bird clips, because a bird, too, is a real object that
comes back at the same place frame after frame (docs/experiment-log.md, Tracking).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gldt_core.track.assignment import assign
from gldt_core.track.boxes import midpoint

#: A chain's next detection must have its centre within this many box diagonals of the last one
#: (plus :data:`GATE_MIN_PX`): at 30 Hz a small drone moves about its own size per frame or less.
GATE_DIAGONALS = 1.5
#: Floor of the gate in pixels, so that 2-3 px boxes with jitter still chain.
GATE_MIN_PX = 4.0


@dataclass
class Candidate:
    """One chain: its last box ``[x1, y1, x2, y2]`` and how many consecutive frames it spans."""

    box: np.ndarray
    frames: int


class LowScoreBirth:
    """Which unclaimed low-score detections have persisted for ``frames`` consecutive frames."""

    def __init__(self, frames: int) -> None:
        if frames < 1:
            raise ValueError(f"low-score birth needs frames >= 1, got {frames}")
        self.frames = int(frames)
        self.reset()

    def reset(self) -> None:
        self.candidates: list[Candidate] = []

    def update(self, dets: np.ndarray, unclaimed: np.ndarray) -> list[int]:
        """Extend the chains with this frame's ``unclaimed`` rows of ``dets`` (``(N, >=4)``);
        return the rows whose chain reached :attr:`frames` (their chains end: they become tracks).

        Each detection extends at most one chain (nearest first), each chain takes at most one
        detection; an unmatched detection starts a chain of one, an unmatched chain is dropped.
        """
        rows = [int(d) for d in np.asarray(unclaimed, dtype=np.int64).reshape(-1)]
        boxes = np.asarray(dets, dtype=np.float64)[rows, :4] if rows else np.zeros((0, 4))
        extended: list[Candidate] = []
        born: list[int] = []
        used = set()
        if self.candidates and rows:
            previous = np.array([c.box for c in self.candidates])
            offset = _centre(previous)[:, None, :] - _centre(boxes)[None, :, :]
            distance = np.hypot(offset[..., 0], offset[..., 1])
            gate = (
                GATE_DIAGONALS * np.hypot(previous[:, 2] - previous[:, 0], previous[:, 3] - previous[:, 1])
                + GATE_MIN_PX
            )
            # Distances in units of each chain's gate, so one limit (1) serves every row.
            relative = distance / gate[:, None]
            for chain_index, column in assign(relative, relative <= 1.0, 1.0):
                used.add(column)
                chain = Candidate(boxes[column].copy(), self.candidates[chain_index].frames + 1)
                if chain.frames >= self.frames:
                    born.append(rows[column])
                else:
                    extended.append(chain)
        for column, row in enumerate(rows):
            if column in used:
                continue
            if self.frames == 1:
                born.append(row)
            else:
                extended.append(Candidate(boxes[column].copy(), 1))
        self.candidates = extended
        return born


def _centre(boxes: np.ndarray) -> np.ndarray:
    return midpoint(boxes[:, :2], boxes[:, 2:4])
