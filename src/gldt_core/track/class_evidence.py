"""Track-level class evidence: what a track is, from every detection it was matched with.

One frame's classifier answer is noisy; a bird may pass as a drone once. Each track therefore
carries the running mean of the class probabilities (drone, bird, airplane) of the detections
it was matched with, and is published as the most probable class with that mean as its
confidence, not as a drone because one frame said so.

Works beside any tracker: a track reported in a frame is matched back to that frame's detections
by IoU (trackers report a matched track at its updated box, which overlaps the detection it was
matched with), so neither tracker needs to carry the probabilities itself.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gldt_core.track.boxes import iou_xyxy

#: Class codes a track can be published with (MOTChallenge: 1 drone, 2 bird, 3 airplane).
CLASS_IDS = (1, 2, 3)
#: Written where no detection has given a track any evidence yet.
UNKNOWN_CLASS_ID = -1
#: A reported track and a detection of the same frame belong together from this IoU on.
MATCH_IOU = 0.3


class ClassEvidence:
    """Running class evidence per track id; :meth:`update` once per frame after the tracker."""

    def __init__(self, forget_after_frames: int = 300) -> None:
        if forget_after_frames < 1:
            raise ValueError(f"forget_after_frames must be >= 1, got {forget_after_frames}")
        self.forget_after_frames = int(forget_after_frames)
        self._sums: dict[int, np.ndarray] = {}
        self._counts: dict[int, int] = {}
        self._last_seen: dict[int, int] = {}
        self._frame = 0

    def reset(self) -> None:
        self._sums.clear()
        self._counts.clear()
        self._last_seen.clear()

    def __len__(self) -> int:
        return len(self._sums)

    def update(self, tracks: np.ndarray, detections: np.ndarray, probabilities: np.ndarray) -> np.ndarray:
        """``(M, 2)`` ``[class_id, confidence]`` for ``tracks`` ``(M, >=5)`` ``[x1, y1, x2, y2, id, ...]``.

        ``detections`` ``(N, >=4)`` are the frame's boxes the tracker was given and
        ``probabilities`` ``(N, 3)`` their drone, bird and airplane probabilities. Each track
        takes the detection it overlaps most (IoU >= :data:`MATCH_IOU`, each detection once).
        """
        self._frame += 1
        tracks = np.asarray(tracks, dtype=np.float64).reshape(
            -1, max(np.shape(tracks)[-1] if np.size(tracks) else 5, 5)
        )
        detections = np.asarray(detections, dtype=np.float64).reshape(
            -1, max(np.shape(detections)[-1] if np.size(detections) else 4, 4)
        )
        probabilities = np.asarray(probabilities, dtype=np.float64).reshape(-1, len(CLASS_IDS))
        if len(probabilities) != len(detections):
            raise ValueError(f"{len(probabilities)} probability rows for {len(detections)} detections")
        if len(tracks) and len(detections):
            overlap = iou_xyxy(tracks[:, :4], detections[:, :4])
            for _ in range(min(len(tracks), len(detections))):
                t, d = np.unravel_index(int(np.argmax(overlap)), overlap.shape)
                if overlap[t, d] < MATCH_IOU:
                    break
                self._add(int(tracks[t, 4]), probabilities[d])
                overlap[t, :] = -1.0
                overlap[:, d] = -1.0
        out = np.empty((len(tracks), 2))
        for row, track_id in enumerate(tracks[:, 4].astype(np.int64)):
            self._last_seen[int(track_id)] = self._frame
            out[row] = self.label(int(track_id))
        self._forget()
        return out

    def label(self, track_id: int) -> tuple[int, float]:
        """``(class_id, confidence)`` of one track; ``(-1, 0.0)`` without evidence."""
        mean = self.probabilities(track_id)
        if mean is None:
            return UNKNOWN_CLASS_ID, 0.0
        best = int(np.argmax(mean))
        return CLASS_IDS[best], float(mean[best])

    def probabilities(self, track_id: int) -> np.ndarray | None:
        """The mean drone, bird and airplane probabilities of the detections matched with one
        track, ``(3,)``; None without evidence (or once it is forgotten)."""
        count = self._counts.get(track_id, 0)
        if count == 0:
            return None
        return self._sums[track_id] / count

    def _add(self, track_id: int, probabilities: np.ndarray) -> None:
        if not np.all(np.isfinite(probabilities)):
            return
        self._sums[track_id] = self._sums.get(track_id, np.zeros(len(CLASS_IDS))) + probabilities
        self._counts[track_id] = self._counts.get(track_id, 0) + 1

    def _forget(self) -> None:
        """Drop tracks not reported for ``forget_after_frames`` frames, so memory stays bounded."""
        stale = [i for i, seen in self._last_seen.items() if self._frame - seen > self.forget_after_frames]
        for track_id in stale:
            self._last_seen.pop(track_id, None)
            self._sums.pop(track_id, None)
            self._counts.pop(track_id, None)


def _published_as_drones(table: np.ndarray) -> np.ndarray:
    return np.isin(table[:, 7], (CLASS_IDS[0], UNKNOWN_CLASS_ID))


def drone_track_rows(rows: np.ndarray) -> int:
    """MOT track rows ``(N, 10)`` published as drones: class (column 8) a drone, or unknown where a
    track has no class evidence yet (a planner must treat those as drones)."""
    return int(_published_as_drones(np.asarray(rows, dtype=np.float64).reshape(-1, 10)).sum())


def drone_tracks(
    rows: np.ndarray, probabilities: Callable[[int], np.ndarray | None]
) -> list[tuple[int, int, np.ndarray | None]]:
    """``(track id, rows published as a drone, mean class probabilities or None)`` of each track in
    MOT ``rows`` with any row published as a drone (:func:`drone_track_rows`), most rows first: what
    the classifier said of the tracks a clip without drones should not have. ``probabilities``
    gives a track's mean class probabilities by id (:meth:`ClassEvidence.probabilities`, or what
    it said when the track was last reported)."""
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 10)
    ids, counts = np.unique(table[_published_as_drones(table), 1].astype(np.int64), return_counts=True)
    order = sorted(zip(ids.tolist(), counts.tolist()), key=lambda pair: (-pair[1], pair[0]))
    return [(track_id, count, probabilities(track_id)) for track_id, count in order]
