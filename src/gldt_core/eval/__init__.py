"""MOT evaluation: HOTA / CLEAR / Identity metrics equal to TrackEval's (see :mod:`.mot_metrics`).

``evaluate_sequence(gt_rows, pred_rows)`` scores one sequence; ``evaluate_many({name: (gt, pred)})``
scores several and combines them as TrackEval does. Ratios are fractions in [0, 1].
"""

from gldt_core.eval.mot_metrics import (
    DEFAULT_DISTRACTOR_CLASSES,
    DEFAULT_TARGET_CLASSES,
    HOTA_ALPHAS,
    METRIC_KEYS,
    ManyResult,
    SequenceCounts,
    box_iou_xywh,
    combine,
    evaluate_many,
    evaluate_sequence,
    sequence_counts,
    summarize,
)

__all__ = [
    "DEFAULT_DISTRACTOR_CLASSES",
    "DEFAULT_TARGET_CLASSES",
    "HOTA_ALPHAS",
    "METRIC_KEYS",
    "ManyResult",
    "SequenceCounts",
    "box_iou_xywh",
    "combine",
    "evaluate_many",
    "evaluate_sequence",
    "sequence_counts",
    "summarize",
]
