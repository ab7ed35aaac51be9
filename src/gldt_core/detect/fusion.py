"""Two detectors' boxes of one frame as one set: the mean of their calibrated scores.

Weighted-box fusion for two models: a box that both detectors report (IoU >= ``match_iou``,
paired greedily, highest IoU first, each box at most once) becomes one box whose corners are the
score-weighted mean of the two, whose score is the mean of the two scores and whose class
probabilities are the mean of the two; it keeps the class id of the higher-scoring one. A box that
only one detector reports keeps its place and half its score: the other detector's score for it
counts as 0. The mean means something only where both scores are calibrated probabilities of the
same event (the second stage's, :mod:`gldt_core.detect.second_stage`).

The pairing is loose (:data:`MATCH_IOU`) because the two detectors box a small drone at different
sizes, as its annotations do (:data:`gldt_core.eval.halmstad_split.LOOSE_IOU`).

:func:`fuse_with_tiles` is the GD frame's fusion (``detector.tile_fusion``): AM-YOLO's boxes with
the local model's over :data:`TILE_SIDE` tiles of the same letterboxed frame. It runs inside
:meth:`gldt_core.detect.GlobalDetector.detect_prepared`, so the offline system and the
``global_detector`` node fuse the same rows. Live, the node may skip the tile pass of a pair that
is already late (:class:`TilePassBudget`), so that fewer of its pairs reach the tracker after its deadline.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from gldt_core.detect.postprocess import Letterbox, drop_degenerate, unletterbox
from gldt_core.eval.detection_metrics import box_iou

if TYPE_CHECKING:
    from gldt_core.detect.local_detector import LocalDetector

#: Lowest IoU at which a box of one detector is taken for the same object as a box of the other.
MATCH_IOU = 0.3

#: Column of the score and of the class id in a detection row (``x1, y1, x2, y2, score, class``).
SCORE = 4
CLASS_ID = 5
#: Side of the local model's tiles over a GD frame's network input [px]: the ROI it learned on.
TILE_SIDE = 300
#: Smallest letterbox scale at which the tiles run. Below it the network input shows the drones
#: smaller than the local model learned them (a 1080p frame is letterboxed at 1/3), and a GD frame
#: keeps AM-YOLO's boxes alone; a 640x512 frame is its own input (scale 1).
TILE_MIN_SCALE = 0.8


def greedy_pairs(iou: np.ndarray, match_iou: float) -> list[tuple[int, int]]:
    """``(row, column)`` pairs of ``iou`` at or above ``match_iou``, highest first, each row and
    column used at most once."""
    pairs: list[tuple[int, int]] = []
    if iou.size == 0:
        return pairs
    rows_used, columns_used = set(), set()
    flat = np.argsort(-iou, axis=None, kind="stable")
    for index in flat:
        row, column = divmod(int(index), iou.shape[1])
        if iou[row, column] < match_iou:
            break
        if row in rows_used or column in columns_used:
            continue
        rows_used.add(row)
        columns_used.add(column)
        pairs.append((row, column))
    return pairs


def fuse_detections(first: np.ndarray, second: np.ndarray, match_iou: float = MATCH_IOU) -> np.ndarray:
    """One frame's detections of two detectors, fused (see the module docstring).

    ``first`` and ``second``: ``(N, C)`` and ``(M, C)`` rows ``[x1, y1, x2, y2, score, ...]`` with
    the same ``C >= 5`` columns; where ``C >= 6`` column 5 is the class id and any further columns
    (class probabilities) are averaged. Returns ``(K, C)`` float32 rows: the pairs first, in
    pairing order, then ``first``'s unpaired boxes, then ``second``'s.
    """
    first = np.asarray(first, dtype=np.float64)
    second = np.asarray(second, dtype=np.float64)
    if first.ndim != 2 or second.ndim != 2 or first.shape[1] != second.shape[1] or first.shape[1] < 5:
        raise ValueError(
            "fuse_detections needs two (N, C) arrays with the same C >= 5 columns, "
            f"got {first.shape} and {second.shape}"
        )
    if not 0.0 < match_iou <= 1.0:
        raise ValueError(f"match_iou must be in (0, 1], got {match_iou}")
    pairs = greedy_pairs(box_iou(first[:, :4], second[:, :4]), match_iou)
    fused = np.zeros((len(pairs), first.shape[1]))
    for k, (i, j) in enumerate(pairs):
        a, b = first[i], second[j]
        weights = np.array([a[SCORE], b[SCORE]])
        weights = weights / weights.sum() if weights.sum() > 0 else np.array([0.5, 0.5])
        fused[k] = (a + b) / 2
        fused[k, :4] = weights[0] * a[:4] + weights[1] * b[:4]
        if first.shape[1] > CLASS_ID:
            fused[k, CLASS_ID] = (a if a[SCORE] >= b[SCORE] else b)[CLASS_ID]
    paired_first = {i for i, _ in pairs}
    paired_second = {j for _, j in pairs}
    alone = np.concatenate(
        [
            first[[i for i in range(len(first)) if i not in paired_first]],
            second[[j for j in range(len(second)) if j not in paired_second]],
        ]
    )
    alone[:, SCORE] /= 2
    return np.concatenate([fused, alone]).astype(np.float32)


def fuse_with_tiles(
    global_rows: np.ndarray,
    local: LocalDetector,
    previous_input: np.ndarray,
    current_input: np.ndarray,
    mapping: Letterbox,
    frame_width: int,
    frame_height: int,
    wanted: Callable[[], bool] | None = None,
) -> np.ndarray:
    """AM-YOLO's ``(N, 9)`` rows of a GD frame (full-frame pixels) fused with the local model's
    over :data:`TILE_SIDE` tiles of the letterboxed pair it saw (``mapping`` takes them back to the
    ``frame_width x frame_height`` frame); ``global_rows`` unchanged where the letterbox scale is
    below :data:`TILE_MIN_SCALE`, or where ``wanted``, asked only for a pair whose tiles would run,
    says False (a live pair too late for the pass). Both detectors' scores must be calibrated, and
    neither cut at the operating threshold yet: the caller cuts the fused rows."""
    if mapping.scale < TILE_MIN_SCALE or (wanted is not None and not wanted()):
        return global_rows
    tiles = local.detect_tiles(current_input, previous_input, TILE_SIDE)
    tiles = drop_degenerate(unletterbox(tiles, mapping, frame_width, frame_height))
    return fuse_detections(global_rows, tiles)


def build_tile_detector(local_model: str | None, global_kwargs: dict[str, Any]) -> LocalDetector:
    """The local detector that a :class:`~gldt_core.detect.GlobalDetector` built with
    ``global_kwargs`` fuses over tiles (its ``tile_detector``): the local model (None: the shipped
    one) with the same providers, threads, classes and second stage, and half the fused score
    threshold (see :func:`fuse_detections`: a box the other detector misses counts half)."""
    from gldt_core.detect.local_detector import LocalDetector
    from gldt_core.detect.second_stage import BESIDE, default_score_threshold
    from gldt_core.detect.session import DetectorConfigError

    if global_kwargs.get("second_stage", BESIDE) is None:
        raise DetectorConfigError(
            "tile fusion needs the second stage (it averages calibrated scores): "
            "set tile_fusion false to run without it"
        )
    threshold = global_kwargs.get("score_threshold")
    if threshold is None:
        threshold = default_score_threshold(True)
    kwargs = {key: value for key, value in global_kwargs.items() if key not in ("model_path", "feature_reuse")}
    return LocalDetector(model_path=local_model, **{**kwargs, "score_threshold": threshold / 2})


#: Tile passes whose median is the expected time of the next (:class:`TilePassBudget`).
TILE_PASS_HISTORY = 9
#: Pairs in a row whose tile pass a :class:`TilePassBudget` skips before it runs one anyway: the
#: expected time is only learnt from passes run, and the machine may have become faster.
TILE_PASS_REMEASURE = 30


class TilePassBudget:
    """Whether a live GD pair still has time for its tile pass (``global_detector``'s ``tile_budget``).

    A pair's detections are due ``budget_s`` after it arrived. Once AM-YOLO's boxes are in,
    ``elapsed_s`` after its arrival, the tile pass runs only if its expected time (the median of
    the last :data:`TILE_PASS_HISTORY` passes) still fits; the first pair, and one after
    :data:`TILE_PASS_REMEASURE` skipped in a row, always run it. ``budget_s`` 0 runs every pass
    (a lockstep replay, which must equal the offline run).
    """

    def __init__(self, budget_s: float) -> None:
        if not budget_s >= 0.0:
            raise ValueError(f"a tile pass budget must be >= 0 s, got {budget_s}")
        self.budget_s = float(budget_s)
        self._passes: deque[float] = deque(maxlen=TILE_PASS_HISTORY)
        self._skipped_in_a_row = 0

    def expected_s(self) -> float | None:
        """The expected time of the next tile pass [s]; None before the first."""
        return float(np.median(self._passes)) if self._passes else None

    def wanted(self, elapsed_s: float) -> bool:
        """Whether a pair whose AM-YOLO pass ended ``elapsed_s`` after its arrival gets its tile
        pass (the caller counts the skips: ``global_detector``'s ``tiles_skipped``)."""
        expected = self.expected_s()
        if (
            self.budget_s == 0.0
            or expected is None
            or self._skipped_in_a_row >= TILE_PASS_REMEASURE
            or elapsed_s + expected <= self.budget_s
        ):
            self._skipped_in_a_row = 0
            return True
        self._skipped_in_a_row += 1
        return False

    def record(self, seconds: float) -> None:
        """How long a tile pass (and its fusion) took [s]."""
        self._passes.append(float(seconds))
