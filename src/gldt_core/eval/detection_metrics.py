"""Detection metrics (numpy only): AP50, AP50:95, AP for small boxes, PR and recall-confidence curves.

Matching follows COCO: per image, detections in descending score order greedily take the unmatched
ground truth with the highest IoU above the threshold; AP is the area under the monotone
precision envelope sampled at 101 recall points. "Small" follows COCO too: ground-truth area
below 32 x 32 pixels in the original frame (unmatched detections count against AP small only when
they are small themselves).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SMALL_AREA = 32.0 * 32.0
IOU_THRESHOLDS = np.round(np.arange(0.5, 0.96, 0.05), 2)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU ``(len(a), len(b))`` of xyxy boxes."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)), dtype=np.float64)
    tl = np.maximum(a[:, None, :2], b[None, :, :2])
    br = np.minimum(a[:, None, 2:4], b[None, :, 2:4])
    inter = np.prod(np.clip(br - tl, 0, None), axis=2)
    area_a = np.prod(np.clip(a[:, 2:4] - a[:, :2], 0, None), axis=1)
    area_b = np.prod(np.clip(b[:, 2:4] - b[:, :2], 0, None), axis=1)
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-12)


@dataclass
class MatchResult:
    """Scores of all detections, which were true positives, and how many ground truths there were."""

    scores: np.ndarray
    true_positive: np.ndarray
    num_gt: int


def match(
    detections: list[np.ndarray],
    ground_truths: list[np.ndarray],
    iou_threshold: float,
    area_range: tuple[float, float] | None = None,
) -> MatchResult:
    """Match per-image ``(N, >=5)`` detections ``[x1,y1,x2,y2,score,...]`` to ``(M, >=4)`` gt boxes.

    With ``area_range``, gts outside it are "ignore" regions: matching them is neither TP nor FP,
    and unmatched detections outside the range are dropped (COCO area semantics).
    """
    if len(detections) != len(ground_truths):
        raise ValueError(f"{len(detections)} detection lists but {len(ground_truths)} ground-truth lists")
    scores: list[np.ndarray] = []
    flags: list[np.ndarray] = []
    num_gt = 0
    for dets, gts in zip(detections, ground_truths):
        dets = np.asarray(dets, dtype=np.float64).reshape(
            -1, max(np.asarray(dets).shape[-1] if np.asarray(dets).size else 5, 5)
        )
        gts = np.asarray(gts, dtype=np.float64).reshape(
            -1, max(np.asarray(gts).shape[-1] if np.asarray(gts).size else 4, 4)
        )
        order = np.argsort(-dets[:, 4], kind="stable")
        dets = dets[order]
        gt_area = np.prod(np.clip(gts[:, 2:4] - gts[:, :2], 0, None), axis=1)
        if area_range is None:
            ignore = np.zeros(len(gts), dtype=bool)
        else:
            ignore = (gt_area < area_range[0]) | (gt_area >= area_range[1])
        num_gt += int((~ignore).sum())
        ious = box_iou(dets[:, :4], gts[:, :4])
        taken = np.zeros(len(gts), dtype=bool)
        keep = np.ones(len(dets), dtype=bool)
        tp = np.zeros(len(dets), dtype=bool)
        for i in range(len(dets)):
            best, best_j = iou_threshold - 1e-12, -1
            # Prefer real (non-ignored) gts, as COCO does.
            for prefer_ignored in (False, True):
                for j in np.flatnonzero((~taken) & (ignore == prefer_ignored)):
                    if ious[i, j] >= best:
                        best, best_j = ious[i, j], int(j)
                if best_j >= 0:
                    break
            if best_j >= 0:
                taken[best_j] = True
                if ignore[best_j]:
                    keep[i] = False
                else:
                    tp[i] = True
            elif area_range is not None:
                area = np.prod(np.clip(dets[i, 2:4] - dets[i, :2], 0, None))
                keep[i] = area_range[0] <= area < area_range[1]
        scores.append(dets[keep, 4])
        flags.append(tp[keep])
    all_scores = np.concatenate(scores) if scores else np.zeros(0)
    all_flags = np.concatenate(flags) if flags else np.zeros(0, dtype=bool)
    order = np.argsort(-all_scores, kind="stable")
    return MatchResult(all_scores[order], all_flags[order], num_gt)


def pr_curve(result: MatchResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Precision, recall and score threshold at every detection, in descending score order."""
    tp = np.cumsum(result.true_positive)
    fp = np.cumsum(~result.true_positive)
    recall = tp / max(result.num_gt, 1)
    precision = tp / np.maximum(tp + fp, 1)
    return precision, recall, result.scores


def average_precision(result: MatchResult) -> float:
    """COCO 101-point interpolated AP; NaN when there is no ground truth."""
    if result.num_gt == 0:
        return float("nan")
    precision, recall, _ = pr_curve(result)
    envelope = np.maximum.accumulate(precision[::-1])[::-1] if len(precision) else precision
    points = np.linspace(0, 1, 101)
    idx = np.searchsorted(recall, points, side="left")
    sampled = np.where(idx < len(envelope), envelope[np.minimum(idx, len(envelope) - 1)] if len(envelope) else 0.0, 0.0)
    return float(np.mean(sampled))


def pr_auc(result: MatchResult) -> float:
    """Area under the (raw, step-wise) precision-recall curve, as in the paper's Fig. 7 legends."""
    if result.num_gt == 0:
        return float("nan")
    precision, recall, _ = pr_curve(result)
    if len(recall) == 0:
        return 0.0
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    widths = np.diff(np.concatenate(([0.0], recall)))
    return float(np.sum(widths * envelope))


def precision_recall_at(result: MatchResult, threshold: float) -> tuple[float, float]:
    """(precision, recall) of the detections scored at ``threshold`` or above (1.0 precision when none)."""
    kept = result.scores >= threshold
    true_positives = float(result.true_positive[kept].sum())
    precision = true_positives / kept.sum() if kept.any() else 1.0
    recall = true_positives / result.num_gt if result.num_gt else 0.0
    return float(precision), float(recall)


def recall_at_confidence(result: MatchResult, thresholds: np.ndarray) -> np.ndarray:
    """Recall reached when only detections with score >= threshold are kept, for each threshold."""
    if result.num_gt == 0:
        return np.full(len(thresholds), np.nan)
    tp_scores = result.scores[result.true_positive]
    return np.array([(tp_scores >= t).sum() / result.num_gt for t in thresholds])


def detection_summary(
    detections: list[np.ndarray], ground_truths: list[np.ndarray], loose_iou: float | None = None
) -> dict[str, float]:
    """AP50, AP50:95, AP_small (at IoU 0.5:0.95), PR AUC at IoU 0.5, and the result at IoU 0.5;
    with ``loose_iou`` also ``ap_loose``, the AP at that IoU (for loosely annotated boxes)."""
    ap_all = [average_precision(match(detections, ground_truths, t)) for t in IOU_THRESHOLDS]
    small = [average_precision(match(detections, ground_truths, t, (0.0, SMALL_AREA))) for t in IOU_THRESHOLDS]
    at50 = match(detections, ground_truths, 0.5)
    summary = {
        "ap50": ap_all[0],
        "ap50_95": float(np.mean(ap_all)),
        "ap_small": float(np.mean(small)),
        "pr_auc": pr_auc(at50),
        "num_gt": float(at50.num_gt),
    }
    if loose_iou is not None:
        summary["ap_loose"] = average_precision(match(detections, ground_truths, loose_iou))
    return summary


#: Below this IoU a detection is not about a ground truth at all (for :func:`error_breakdown`).
NEAR_IOU = 0.1


def error_breakdown(
    detections: list[np.ndarray],
    ground_truths: list[np.ndarray],
    target_class: int,
    score_threshold: float,
    iou_threshold: float = 0.5,
) -> dict[str, float]:
    """Where a detector loses AP on one class: what became of each ground truth, and what its
    false positives at ``score_threshold`` are.

    AP alone does not say whether to fix the class decision, the boxes or the recall. Per image,
    ``detections`` are ``(N, 6)`` rows ``x1, y1, x2, y2, score, class`` of *every* class (as the
    detector reports them, each box with its one best class) and ``ground_truths`` ``(M, >=4)``
    boxes of ``target_class``. Each ground truth lands in exactly one bucket, tested in order over
    every box given, whatever its score (the same boxes AP ranks):

    * ``found``: a ``target_class`` box at IoU >= ``iou_threshold``;
    * ``other_class``: only a box of another class there (the class decision lost it);
    * ``poorly_placed``: a ``target_class`` box at IoU in [0.1, ``iou_threshold``) (the box lost it);
    * ``missed``: nothing near it.

    False positives are ``target_class`` boxes at ``score_threshold`` or above that
    :func:`match` leaves unmatched: ``fp_on_object`` when they overlap a ground truth by at least
    0.1 IoU (a second or misplaced box on a real object), ``fp_background`` otherwise. All counts
    are totals over the images.
    """
    if len(detections) != len(ground_truths):
        raise ValueError(f"{len(detections)} detection lists but {len(ground_truths)} ground-truth lists")
    out = dict.fromkeys(
        ("num_gt", "found", "other_class", "poorly_placed", "missed", "fp_on_object", "fp_background"), 0.0
    )
    for dets, gts in zip(detections, ground_truths):
        dets = np.asarray(dets, dtype=np.float64).reshape(-1, 6)
        gts = np.asarray(gts, dtype=np.float64).reshape(-1, 4) if np.asarray(gts).size else np.zeros((0, 4))
        ious = box_iou(dets[:, :4], gts[:, :4])  # (N, M)
        own = dets[:, 5] == target_class
        for j in range(len(gts)):
            column = ious[:, j]
            if (column[own] >= iou_threshold).any():
                out["found"] += 1
            elif (column[~own] >= iou_threshold).any():
                out["other_class"] += 1
            elif (column[own] >= NEAR_IOU).any():
                out["poorly_placed"] += 1
            else:
                out["missed"] += 1
        out["num_gt"] += len(gts)
        rows = np.flatnonzero(own & (dets[:, 4] >= score_threshold))
        # Sorted as match() sorts (stable, by score), so its flags line up with these rows.
        rows = rows[np.argsort(-dets[rows, 4], kind="stable")]
        false_positive = ~match([dets[rows, :5]], [gts], iou_threshold).true_positive
        near = ious[rows[false_positive]].max(axis=1, initial=0.0) >= NEAR_IOU
        out["fp_on_object"] += float(near.sum())
        out["fp_background"] += float((~near).sum())
    return out
