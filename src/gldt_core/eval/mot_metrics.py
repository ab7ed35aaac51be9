"""MOT metrics (HOTA, CLEAR, Identity) computed the way TrackEval 1.3.0 computes them.

Why our own code and not TrackEval at run time: TrackEval is a research tool that reads a fixed
folder layout, prints its config and ships only as a test dependency here. The algorithms below
follow its definitions step for step (same similarity, same Hungarian matchings, same eps
handling), and ``tests/core/test_eval_trackeval_equality.py`` proves equality with TrackEval itself to
1e-6 on sequences with empty frames, id reuse, distractors and no matches.

Inputs are MOTChallenge ``(N, 10)`` arrays as returned by :func:`gldt_core.io.mot.read_mot`:
``frame, id, x, y, w, h, score/considered, class, visibility, -``.

Ground-truth preprocessing (TrackEval's MOT17 preprocessing with the drone classes of this project):

* rows whose class (column 7) is in ``target_classes`` (default ``{1}``, drone) and whose column 6
  ("considered") is non-zero are the targets; a missing class (``-1``) counts as a target, so
  six-column ground truth works;
* rows whose class is in ``distractor_classes`` (default ``{2, 3, 4}``: bird, airplane,
  helicopter) are distractors: a prediction matched to one (IoU >= 0.5, Hungarian over all gt rows
  of the frame, exactly as TrackEval) is removed, so a tracker is not punished for following a
  bird, and it is not rewarded either;
* every other gt row (zero-confidence targets, unknown classes) is dropped; predictions overlapping
  them stay and count as false positives, as in TrackEval.

Prediction rows use only frame, id and box; their score column is ignored.

All returned ratios are fractions in [0, 1] (TrackEval's internal convention; the CLI prints
percentages). Counts (IDSW, FP, FN, Frag, ...) are integers.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
from scipy.optimize import linear_sum_assignment

EPS = float(np.finfo("float").eps)
#: HOTA's localisation thresholds alpha = 0.05, 0.10, ..., 0.95 (TrackEval's array_labels).
HOTA_ALPHAS = np.arange(0.05, 0.99, 0.05)
DEFAULT_TARGET_CLASSES = (1,)
DEFAULT_DISTRACTOR_CLASSES = (2, 3, 4)

#: Keys of the dict returned by :func:`evaluate_sequence` and :func:`evaluate_many`.
METRIC_KEYS = (
    "HOTA",
    "DetA",
    "AssA",
    "DetRe",
    "DetPr",
    "AssRe",
    "AssPr",
    "LocA",
    "MOTA",
    "MOTP",
    "MODA",
    "IDF1",
    "IDP",
    "IDR",
    "IDSW",
    "FP",
    "FN",
    "TP",
    "Frag",
    "MT",
    "PT",
    "ML",
    "IDTP",
    "IDFP",
    "IDFN",
    "GT_Dets",
    "GT_IDs",
    "Pred_Dets",
    "Pred_IDs",
    "Frames",
)


@dataclass
class _Frames:
    """Per-frame id arrays (relabelled 0..n-1) and gt x pred IoU matrices after preprocessing."""

    gt_ids: list[np.ndarray]
    pred_ids: list[np.ndarray]
    similarity: list[np.ndarray]
    num_gt_ids: int
    num_pred_ids: int
    num_gt_dets: int
    num_pred_dets: int


@dataclass
class SequenceCounts:
    """Everything needed to report one sequence and to combine sequences like TrackEval."""

    hota_tp: np.ndarray
    hota_fn: np.ndarray
    hota_fp: np.ndarray
    ass_a: np.ndarray
    ass_re: np.ndarray
    ass_pr: np.ndarray
    loc_a: np.ndarray
    clear: dict[str, float] = field(default_factory=dict)
    identity: dict[str, float] = field(default_factory=dict)
    extra: dict[str, int] = field(default_factory=dict)


def box_iou_xywh(boxes1: np.ndarray, boxes2: np.ndarray) -> np.ndarray:
    """IoU matrix of ``[x, y, w, h]`` boxes, with TrackEval's handling of degenerate boxes."""
    b1 = np.array(boxes1, dtype=np.float64, copy=True).reshape(-1, 4)
    b2 = np.array(boxes2, dtype=np.float64, copy=True).reshape(-1, 4)
    b1[:, 2] = b1[:, 0] + b1[:, 2]
    b1[:, 3] = b1[:, 1] + b1[:, 3]
    b2[:, 2] = b2[:, 0] + b2[:, 2]
    b2[:, 3] = b2[:, 1] + b2[:, 3]
    min_ = np.minimum(b1[:, np.newaxis, :], b2[np.newaxis, :, :])
    max_ = np.maximum(b1[:, np.newaxis, :], b2[np.newaxis, :, :])
    intersection = np.maximum(min_[..., 2] - max_[..., 0], 0) * np.maximum(min_[..., 3] - max_[..., 1], 0)
    area1 = (b1[..., 2] - b1[..., 0]) * (b1[..., 3] - b1[..., 1])
    area2 = (b2[..., 2] - b2[..., 0]) * (b2[..., 3] - b2[..., 1])
    union = area1[:, np.newaxis] + area2[np.newaxis, :] - intersection
    intersection[area1 <= 0 + EPS, :] = 0
    intersection[:, area2 <= 0 + EPS] = 0
    intersection[union <= 0 + EPS] = 0
    union[union <= 0 + EPS] = 1
    return intersection / union


def _as_rows(rows: np.ndarray, what: str) -> np.ndarray:
    table = np.asarray(rows, dtype=np.float64)
    if table.size == 0:
        return np.zeros((0, 10), dtype=np.float64)
    if table.ndim != 2 or table.shape[1] < 6:
        raise ValueError(f"{what}: expected an (N, >=6) MOT array, got shape {table.shape}")
    if not np.all(np.isfinite(table[:, :6])):
        bad = int(np.flatnonzero(~np.all(np.isfinite(table[:, :6]), axis=1))[0])
        raise ValueError(f"{what}: row {bad} (frame {table[bad, 0]:g}) has a NaN or infinite field")
    if table.shape[1] < 10:
        table = np.hstack([table, np.full((table.shape[0], 10 - table.shape[1]), -1.0)])
    if np.any(table[:, 0] < 1) or np.any(table[:, 0] != np.round(table[:, 0])):
        bad = int(np.flatnonzero((table[:, 0] < 1) | (table[:, 0] != np.round(table[:, 0])))[0])
        raise ValueError(f"{what}: row {bad} has frame {table[bad, 0]:g}; frames are 1-based integers")
    return table


def _group_by_frame(table: np.ndarray, frames: np.ndarray) -> list[np.ndarray]:
    """The rows of each of ``frames`` (sorted frame numbers), in that order."""
    order = np.argsort(table[:, 0], kind="stable")
    table = table[order]
    starts = np.searchsorted(table[:, 0].astype(np.int64), np.append(frames, np.iinfo(np.int64).max))
    return [table[starts[i] : starts[i + 1]] for i in range(len(frames))]


@dataclass(frozen=True)
class FrameView:
    """One frame as the metrics see it: ids, the IoU of every (gt, prediction) pair, the ground
    truth that counts (a target class, not flagged 0) and the predictions that count (not matched
    at IoU 0.5 to a distractor, as TrackEval's MOT preprocessing removes them)."""

    gt_ids: np.ndarray
    pred_ids: np.ndarray
    similarity: np.ndarray
    keep_gt: np.ndarray
    keep_pred: np.ndarray
    is_distractor: np.ndarray


def frame_view(frame: int, g: np.ndarray, p: np.ndarray, targets: np.ndarray, distractors: np.ndarray) -> FrameView:
    """The :class:`FrameView` of one frame's gt rows ``g`` and prediction rows ``p``; one line
    naming the frame when its ids are not usable."""
    g_ids = g[:, 1].astype(np.int64)
    p_ids = p[:, 1].astype(np.int64)
    if len(np.unique(p_ids)) != len(p_ids):
        raise ValueError(f"predictions: frame {frame} reports the same track id twice")
    if len(np.unique(g_ids)) != len(g_ids):
        raise ValueError(f"ground truth: frame {frame} has the same object id twice")
    if np.any(p_ids < 0):
        raise ValueError(f"predictions: frame {frame} has a negative track id")
    similarity = box_iou_xywh(g[:, 2:6], p[:, 2:6])
    classes = g[:, 7].astype(np.int64)
    is_distractor = np.isin(classes, distractors)
    keep_pred = np.ones(len(p), dtype=bool)
    if len(g) > 0 and len(p) > 0 and len(distractors) > 0:
        matching = similarity.copy()
        matching[matching < 0.5 - EPS] = 0
        rows, cols = linear_sum_assignment(-matching)
        matched = matching[rows, cols] > 0 + EPS
        rows, cols = rows[matched], cols[matched]
        keep_pred[cols[is_distractor[rows]]] = False
    keep_gt = (g[:, 6] != 0) & (np.isin(classes, targets) | (classes == -1))
    return FrameView(g_ids, p_ids, similarity, keep_gt, keep_pred, is_distractor)


def clear_matches(
    gt_ids: np.ndarray, pred_ids: np.ndarray, previous: np.ndarray, similarity: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """CLEAR's matching of one frame (TrackEval): rows into ``gt_ids`` and columns into
    ``pred_ids`` of the matched pairs. ``previous`` holds each gt id's prediction id matched in
    the last frame with a match (anything else where none), which a pair keeps whenever its IoU
    passes ``threshold``."""
    score = 1000 * (pred_ids[np.newaxis, :] == previous[:, np.newaxis]) + similarity
    score[similarity < threshold - EPS] = 0
    rows, cols = linear_sum_assignment(-score)
    ok = score[rows, cols] > 0 + EPS
    return rows[ok], cols[ok]


def _preprocess(
    gt: np.ndarray,
    pred: np.ndarray,
    num_frames: int | None,
    target_classes: Iterable[int],
    distractor_classes: Iterable[int],
) -> tuple[_Frames, int]:
    gt = _as_rows(gt, "ground truth")
    pred = _as_rows(pred, "predictions")
    last = int(max(gt[:, 0].max(initial=0), pred[:, 0].max(initial=0)))
    if num_frames is None:
        num_frames = last
    elif num_frames < last:
        raise ValueError(f"num_frames={num_frames} but the data has rows up to frame {last}")
    targets = np.asarray(sorted(set(int(c) for c in target_classes)), dtype=np.int64)
    distractors = np.asarray(sorted(set(int(c) for c in distractor_classes)), dtype=np.int64)
    # Only frames with a row: a frame without ground truth and predictions changes no metric
    # (TrackEval skips it too), and a lone row at frame 100,000,000 must not size anything.
    present = np.union1d(gt[:, 0], pred[:, 0]).astype(np.int64)
    gt_frames = _group_by_frame(gt, present)
    pred_frames = _group_by_frame(pred, present)

    gt_ids_t: list[np.ndarray] = []
    pred_ids_t: list[np.ndarray] = []
    sims_t: list[np.ndarray] = []
    for frame, g, p in zip(present.tolist(), gt_frames, pred_frames):
        view = frame_view(frame, g, p, targets, distractors)
        gt_ids_t.append(view.gt_ids[view.keep_gt])
        pred_ids_t.append(view.pred_ids[view.keep_pred])
        sims_t.append(view.similarity[view.keep_gt][:, view.keep_pred])

    def relabel(ids_per_frame: list[np.ndarray]) -> int:
        present = [ids for ids in ids_per_frame if len(ids)]
        if not present:
            return 0
        unique = np.unique(np.concatenate(present))
        for t, ids in enumerate(ids_per_frame):
            if len(ids):
                ids_per_frame[t] = np.searchsorted(unique, ids)
        return len(unique)

    num_gt_ids = relabel(gt_ids_t)
    num_pred_ids = relabel(pred_ids_t)
    frames = _Frames(
        gt_ids=gt_ids_t,
        pred_ids=pred_ids_t,
        similarity=sims_t,
        num_gt_ids=num_gt_ids,
        num_pred_ids=num_pred_ids,
        num_gt_dets=int(sum(len(x) for x in gt_ids_t)),
        num_pred_dets=int(sum(len(x) for x in pred_ids_t)),
    )
    return frames, num_frames


def _hota(data: _Frames) -> dict[str, np.ndarray]:
    n_alpha = len(HOTA_ALPHAS)
    tp = np.zeros(n_alpha)
    fn = np.zeros(n_alpha)
    fp = np.zeros(n_alpha)
    loc = np.zeros(n_alpha)
    out = {
        "tp": tp,
        "fn": fn,
        "fp": fp,
        "loc": loc,
        "ass_a": np.zeros(n_alpha),
        "ass_re": np.zeros(n_alpha),
        "ass_pr": np.zeros(n_alpha),
    }
    if data.num_pred_dets == 0:
        fn[:] = data.num_gt_dets
        loc[:] = 1.0
        return out
    if data.num_gt_dets == 0:
        fp[:] = data.num_pred_dets
        loc[:] = 1.0
        return out
    potential = np.zeros((data.num_gt_ids, data.num_pred_ids))
    gt_count = np.zeros((data.num_gt_ids, 1))
    pred_count = np.zeros((1, data.num_pred_ids))
    for g_ids, p_ids, sim in zip(data.gt_ids, data.pred_ids, data.similarity):
        denom = sim.sum(0)[np.newaxis, :] + sim.sum(1)[:, np.newaxis] - sim
        sim_iou = np.zeros_like(sim)
        mask = denom > 0 + EPS
        sim_iou[mask] = sim[mask] / denom[mask]
        potential[g_ids[:, np.newaxis], p_ids[np.newaxis, :]] += sim_iou
        gt_count[g_ids] += 1
        pred_count[0, p_ids] += 1
    global_alignment = potential / (gt_count + pred_count - potential)
    matches = np.zeros((n_alpha, data.num_gt_ids, data.num_pred_ids))
    for g_ids, p_ids, sim in zip(data.gt_ids, data.pred_ids, data.similarity):
        if len(g_ids) == 0:
            fp += len(p_ids)
            continue
        if len(p_ids) == 0:
            fn += len(g_ids)
            continue
        score = global_alignment[g_ids[:, np.newaxis], p_ids[np.newaxis, :]] * sim
        rows, cols = linear_sum_assignment(-score)
        matched_sim = sim[rows, cols]
        for a, alpha in enumerate(HOTA_ALPHAS):
            ok = matched_sim >= alpha - EPS
            num = int(ok.sum())
            tp[a] += num
            fn[a] += len(g_ids) - num
            fp[a] += len(p_ids) - num
            if num > 0:
                loc[a] += sum(matched_sim[ok])
                matches[a, g_ids[rows[ok]], p_ids[cols[ok]]] += 1
    for a in range(n_alpha):
        m = matches[a]
        out["ass_a"][a] = np.sum(m * (m / np.maximum(1, gt_count + pred_count - m))) / np.maximum(1, tp[a])
        out["ass_re"][a] = np.sum(m * (m / np.maximum(1, gt_count))) / np.maximum(1, tp[a])
        out["ass_pr"][a] = np.sum(m * (m / np.maximum(1, pred_count))) / np.maximum(1, tp[a])
    out["loc"] = np.maximum(1e-10, loc) / np.maximum(1e-10, tp)
    return out


def _clear(data: _Frames, num_frames: int, threshold: float) -> dict[str, float]:
    res = {k: 0.0 for k in ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag", "MOTP_sum")}
    res["CLR_Frames"] = num_frames
    if data.num_pred_dets == 0:
        res["CLR_FN"] = data.num_gt_dets
        res["ML"] = data.num_gt_ids
        return res
    if data.num_gt_dets == 0:
        res["CLR_FP"] = data.num_pred_dets
        return res
    n = data.num_gt_ids
    gt_count = np.zeros(n)
    gt_matched = np.zeros(n)
    gt_frag = np.zeros(n)
    prev_id = np.full(n, np.nan)
    prev_step_id = np.full(n, np.nan)
    for g_ids, p_ids, sim in zip(data.gt_ids, data.pred_ids, data.similarity):
        if len(g_ids) == 0:
            res["CLR_FP"] += len(p_ids)
            continue
        if len(p_ids) == 0:
            res["CLR_FN"] += len(g_ids)
            gt_count[g_ids] += 1
            continue
        rows, cols = clear_matches(g_ids, p_ids, prev_step_id[g_ids], sim, threshold)
        matched_gt = g_ids[rows]
        matched_pred = p_ids[cols]
        prev_matched = prev_id[matched_gt]
        res["IDSW"] += int(np.sum(~np.isnan(prev_matched) & (matched_pred != prev_matched)))
        gt_count[g_ids] += 1
        gt_matched[matched_gt] += 1
        not_prev = np.isnan(prev_step_id)
        prev_id[matched_gt] = matched_pred
        prev_step_id[:] = np.nan
        prev_step_id[matched_gt] = matched_pred
        gt_frag += not_prev & ~np.isnan(prev_step_id)
        res["CLR_TP"] += len(matched_gt)
        res["CLR_FN"] += len(g_ids) - len(matched_gt)
        res["CLR_FP"] += len(p_ids) - len(matched_gt)
        if len(matched_gt):
            res["MOTP_sum"] += sum(sim[rows, cols])
    ratio = gt_matched[gt_count > 0] / gt_count[gt_count > 0]
    res["MT"] = int(np.sum(ratio > 0.8))
    res["PT"] = int(np.sum(ratio >= 0.2)) - res["MT"]
    res["ML"] = n - res["MT"] - res["PT"]
    res["Frag"] = int(np.sum(gt_frag[gt_frag > 0] - 1))
    return res


def _identity(data: _Frames, threshold: float) -> dict[str, float]:
    if data.num_pred_dets == 0:
        return {"IDTP": 0, "IDFN": data.num_gt_dets, "IDFP": 0}
    if data.num_gt_dets == 0:
        return {"IDTP": 0, "IDFN": 0, "IDFP": data.num_pred_dets}
    ng, npred = data.num_gt_ids, data.num_pred_ids
    potential = np.zeros((ng, npred))
    gt_count = np.zeros(ng)
    pred_count = np.zeros(npred)
    for g_ids, p_ids, sim in zip(data.gt_ids, data.pred_ids, data.similarity):
        gi, pi = np.nonzero(sim >= threshold)
        np.add.at(potential, (g_ids[gi], p_ids[pi]), 1)
        gt_count[g_ids] += 1
        pred_count[p_ids] += 1
    size = ng + npred
    fp_mat = np.zeros((size, size))
    fn_mat = np.zeros((size, size))
    fp_mat[ng:, :npred] = 1e10
    fn_mat[:ng, npred:] = 1e10
    fn_mat[:ng, :npred] = gt_count[:, np.newaxis]
    fn_mat[np.arange(ng), npred + np.arange(ng)] = gt_count
    fp_mat[:ng, :npred] = pred_count[np.newaxis, :]
    fp_mat[ng + np.arange(npred), np.arange(npred)] = pred_count
    fn_mat[:ng, :npred] -= potential
    fp_mat[:ng, :npred] -= potential
    rows, cols = linear_sum_assignment(fn_mat + fp_mat)
    idfn = int(fn_mat[rows, cols].sum())
    idfp = int(fp_mat[rows, cols].sum())
    return {"IDTP": int(gt_count.sum()) - idfn, "IDFN": idfn, "IDFP": idfp}


def sequence_counts(
    gt_rows: np.ndarray,
    pred_rows: np.ndarray,
    *,
    num_frames: int | None = None,
    target_classes: Iterable[int] = DEFAULT_TARGET_CLASSES,
    distractor_classes: Iterable[int] = DEFAULT_DISTRACTOR_CLASSES,
    threshold: float = 0.5,
) -> SequenceCounts:
    """Raw per-sequence counts (what :func:`evaluate_many` sums); see the module doc for classes."""
    data, frames = _preprocess(gt_rows, pred_rows, num_frames, target_classes, distractor_classes)
    hota = _hota(data)
    return SequenceCounts(
        hota_tp=hota["tp"],
        hota_fn=hota["fn"],
        hota_fp=hota["fp"],
        ass_a=hota["ass_a"],
        ass_re=hota["ass_re"],
        ass_pr=hota["ass_pr"],
        loc_a=hota["loc"],
        clear=_clear(data, frames, threshold),
        identity=_identity(data, threshold),
        extra={
            "GT_Dets": data.num_gt_dets,
            "GT_IDs": data.num_gt_ids,
            "Pred_Dets": data.num_pred_dets,
            "Pred_IDs": data.num_pred_ids,
            "Frames": frames,
        },
    )


def _final(
    tp: np.ndarray,
    fn: np.ndarray,
    fp: np.ndarray,
    ass_a: np.ndarray,
    ass_re: np.ndarray,
    ass_pr: np.ndarray,
    loc_a: np.ndarray,
    clear: Mapping[str, float],
    identity: Mapping[str, float],
    extra: Mapping[str, int],
) -> dict[str, float]:
    det_re = tp / np.maximum(1, tp + fn)
    det_pr = tp / np.maximum(1, tp + fp)
    det_a = tp / np.maximum(1, tp + fn + fp)
    hota = np.sqrt(det_a * ass_a)
    c_tp, c_fn, c_fp, idsw = clear["CLR_TP"], clear["CLR_FN"], clear["CLR_FP"], clear["IDSW"]
    denom = max(1.0, c_tp + c_fn)
    idtp, idfn, idfp = identity["IDTP"], identity["IDFN"], identity["IDFP"]
    out = {
        "HOTA": float(np.mean(hota)),
        "DetA": float(np.mean(det_a)),
        "AssA": float(np.mean(ass_a)),
        "DetRe": float(np.mean(det_re)),
        "DetPr": float(np.mean(det_pr)),
        "AssRe": float(np.mean(ass_re)),
        "AssPr": float(np.mean(ass_pr)),
        "LocA": float(np.mean(loc_a)),
        "MOTA": float((c_tp - c_fp - idsw) / denom),
        "MOTP": float(clear["MOTP_sum"] / max(1.0, c_tp)),
        "MODA": float((c_tp - c_fp) / denom),
        "IDF1": float(idtp / max(1.0, idtp + 0.5 * idfp + 0.5 * idfn)),
        "IDP": float(idtp / max(1.0, idtp + idfp)),
        "IDR": float(idtp / max(1.0, idtp + idfn)),
        "IDSW": int(idsw),
        "FP": int(c_fp),
        "FN": int(c_fn),
        "TP": int(c_tp),
        "Frag": int(clear["Frag"]),
        "MT": int(clear["MT"]),
        "PT": int(clear["PT"]),
        "ML": int(clear["ML"]),
        "IDTP": int(idtp),
        "IDFP": int(idfp),
        "IDFN": int(idfn),
    }
    out.update({k: int(v) for k, v in extra.items()})
    return out


def summarize(counts: SequenceCounts) -> dict[str, float]:
    """Turn one sequence's counts into the metric dict (fractions; counts as ints).

    A sequence without any ground truth but with predictions gets MOTA = MODA = 0 (not -FP), as
    TrackEval reports it per sequence; combined results still count those false positives.
    """
    out = _final(
        counts.hota_tp,
        counts.hota_fn,
        counts.hota_fp,
        counts.ass_a,
        counts.ass_re,
        counts.ass_pr,
        counts.loc_a,
        counts.clear,
        counts.identity,
        counts.extra,
    )
    if counts.extra["GT_Dets"] == 0:
        out["MOTA"] = 0.0
        out["MODA"] = 0.0
    return out


def combine(all_counts: Iterable[SequenceCounts]) -> dict[str, float]:
    """Combine sequences as TrackEval's ``combine_sequences``: counts summed, HOTA's association
    scores averaged with weights HOTA_TP per alpha, LocA weighted the same way."""
    items = list(all_counts)
    n_alpha = len(HOTA_ALPHAS)
    tp = sum((c.hota_tp for c in items), np.zeros(n_alpha))
    fn = sum((c.hota_fn for c in items), np.zeros(n_alpha))
    fp = sum((c.hota_fp for c in items), np.zeros(n_alpha))

    def weighted(name: str) -> np.ndarray:
        total = sum((getattr(c, name) * c.hota_tp for c in items), np.zeros(n_alpha))
        return total / np.maximum(1.0, tp)

    loc_sum = sum((c.loc_a * c.hota_tp for c in items), np.zeros(n_alpha))
    loc_a = np.maximum(1e-10, loc_sum) / np.maximum(1e-10, tp)
    clear_keys = ("CLR_TP", "CLR_FN", "CLR_FP", "IDSW", "MT", "PT", "ML", "Frag", "MOTP_sum", "CLR_Frames")
    clear = {k: sum(c.clear[k] for c in items) for k in clear_keys}
    identity = {k: sum(c.identity[k] for c in items) for k in ("IDTP", "IDFN", "IDFP")}
    extra = {k: sum(c.extra[k] for c in items) for k in ("GT_Dets", "GT_IDs", "Pred_Dets", "Pred_IDs", "Frames")}
    return _final(tp, fn, fp, weighted("ass_a"), weighted("ass_re"), weighted("ass_pr"), loc_a, clear, identity, extra)


def evaluate_sequence(
    gt_rows: np.ndarray,
    pred_rows: np.ndarray,
    *,
    num_frames: int | None = None,
    target_classes: Iterable[int] = DEFAULT_TARGET_CLASSES,
    distractor_classes: Iterable[int] = DEFAULT_DISTRACTOR_CLASSES,
    threshold: float = 0.5,
) -> dict[str, float]:
    """HOTA, DetA, AssA, MOTA, MOTP, IDF1, IDSW, FP, FN, Frag, ... of one sequence.

    ``num_frames`` defaults to the last frame present in either input (it only changes nothing but
    the ``Frames`` count, since empty frames add no error). Ratios are fractions in [0, 1].
    """
    return summarize(
        sequence_counts(
            gt_rows,
            pred_rows,
            num_frames=num_frames,
            target_classes=target_classes,
            distractor_classes=distractor_classes,
            threshold=threshold,
        )
    )


class ManyResult(TypedDict):
    """What :func:`evaluate_many` returns: the combined metrics and each sequence's own."""

    combined: dict[str, float]
    per_sequence: dict[str, dict[str, float]]


def evaluate_many(
    sequences: Mapping[str, tuple[np.ndarray, np.ndarray]],
    *,
    target_classes: Iterable[int] = DEFAULT_TARGET_CLASSES,
    distractor_classes: Iterable[int] = DEFAULT_DISTRACTOR_CLASSES,
    threshold: float = 0.5,
) -> ManyResult:
    """Evaluate ``{name: (gt_rows, pred_rows)}`` and combine them the way TrackEval does.

    Returns ``{"combined": metrics, "per_sequence": {name: metrics}}``.
    """
    if not sequences:
        raise ValueError("evaluate_many: no sequences given")
    counts = {}
    for name, (gt, pred) in sequences.items():
        try:
            counts[name] = sequence_counts(
                gt, pred, target_classes=target_classes, distractor_classes=distractor_classes, threshold=threshold
            )
        except ValueError as error:
            raise ValueError(f"sequence {name}: {error}") from None
    return {
        "combined": combine(counts.values()),
        "per_sequence": {name: summarize(c) for name, c in counts.items()},
    }
