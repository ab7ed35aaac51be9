"""Where the identity switches come from: every CLEAR IDSW of a sequence, classified by cause.

:func:`classify_id_switches` takes what any tracker leaves behind (its MOT output rows), the
ground truth and the detections the tracker was given, and returns one :class:`IdSwitchEvent` per
identity switch with a category from :data:`CATEGORIES`. It needs nothing from the tracker's
internals, so JPTrack, our ByteTrack and boxmot's peers are classified by the same rules and their
breakdowns can be put side by side (:func:`format_id_switch_table`).

**Which switches.** The events are exactly the switches TrackEval's CLEAR metric counts, so
``report.total == evaluate_sequence(gt, pred)["IDSW"]``: the same ground-truth preprocessing
(targets, distractors and the predictions matched to them removed; see
:mod:`gldt_core.eval.mot_metrics`), the same per-frame Hungarian matching on IoU >= ``iou_threshold``
with the 1000-point bonus for keeping the previous frame's pair, and a switch whenever a gt object
is matched to a track id other than the one it was last matched to (however many frames ago).
This includes the *return* of an object's own earlier id after an intruder held it for a while:
TrackEval counts that second change as a switch too (the last matched id was the intruder's).

**What each track did before.** Every output row of a track is labelled per frame: *matched* to
gt object ``h`` (the CLEAR matching above), *near* ``h`` (unmatched, but the nearest target box
whose centre is within ``near_distance`` box sizes, the size being the largest side of either
box; at equal distance the lower id), on a *distractor* (matched to a bird by the preprocessing,
or unmatched and nearest to one) or on *clutter* (unmatched and near nothing).

**Which detections the object had.** Column 1 of ``det_rows`` is the provenance of each
detection: the gt object id it was made from, ``-1`` for clutter, ``-2`` for a distractor. When
the whole column is ``-1`` (a real detector's output, or a stream without provenance) it is
assigned here: per frame, a Hungarian matching of the detections to all gt rows on IoU >=
``provenance_iou``; a detection matched to a target gets its id, to a distractor ``-2``, and
anything else ``-1``. An object's *detection gap* is a run of at least ``min_gap_frames``
consecutive frames, between its first and its last frame as a target in the gt, in which it has no
detection; frames in which it is missing from the gt (out of view, or not considered) count as
undetected, so a new id after the object left the view and came back is a birth after a gap.

**Categories.** A switch at frame ``f`` moves gt object ``g`` from its last matched id ``P``
(matched to ``g`` last at frame ``m``) to the new id ``N``. Walk back through ``N``'s rows before
``f``, skipping the trailing rows where ``N`` was *near* ``g`` (a track closing in on the object,
or shadowing it while ``P`` held the match); the first skipped row is where ``N`` *arrived* at
``g`` (``f`` itself when nothing was skipped). The row reached decides:

1. ``fragment return``: it is a row matched to ``g``: ``N`` is one of ``g``'s own earlier ids
   coming back (``P`` was an intruder, or a duplicate that held the object meanwhile). Checked
   first, whenever ``N`` arrived.
2. ``other``: ``N`` arrived more than ``recent_s`` seconds before ``f``: it followed the object
   unmatched (a badly placed or duplicate box) for a long time before it took over, so the switch
   has no single moment that explains it. Rare on normal streams.
3. ``swap onto another target``: it is a row matched to, or near, another target ``h`` and ``N``
   has no hole of ``lost_gap_frames`` or more frames in its output from that row to ``f``: a
   continuously tracked id jumped from ``h`` to ``g`` (a wrong association at a crossing: the
   JCMA / IoU stage).
4. ``recovery onto another target``: as 3, but ``N``'s output has such a hole: a lost track,
   last seen on ``h``, was re-attached to ``g`` (a lost-track recovery such as PMR's, or the first
   stage re-matching a recently lost track, chose the wrong object). Trackers that report only the
   tracks updated in a frame (ours, ByteTrack, boxmot's) leave a hole for every frame a track was
   lost; with the default ``lost_gap_frames = 1`` any hole counts.
5. ``recovery from clutter``: it is a row on clutter or a distractor: ``N`` had been following a
   false positive or a bird and then took over ``g``.
6. no row is left: ``N`` was born on ``g`` (its first row, or ``f``, is its birth ``b``):

   * ``birth after a detection gap`` when ``g`` has a detection gap of ``min_gap_frames`` or more
     that overlaps ``(m, f]`` (after the old id's last match) and ``b`` is not before the gap's
     start: the old track died during the occlusion or miss burst and a new one was born during
     or after it;
   * ``birth while detected`` otherwise: the object was detected the whole time (or the new id
     was born before the gap), so the old track was dropped or not matched although detections
     existed (a motion / gating failure) or a duplicate track was started.

Each event also says what became of ``P`` at ``f`` (``prev_fate``): still matched to another gt,
present but unmatched, absent for a while, or ended (no later row). Two ids that take turns on
one object (each reported every other frame) show as a run of fragment returns, one per change.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from gldt_core.eval.mot_metrics import (
    DEFAULT_DISTRACTOR_CLASSES,
    DEFAULT_TARGET_CLASSES,
    EPS,
    _as_rows,
    _group_by_frame,
    box_iou_xywh,
    clear_matches,
    frame_view,
)

SWAP = "swap onto another target"
RECOVERY_OTHER = "recovery onto another target"
RECOVERY_CLUTTER = "recovery from clutter"
BIRTH_GAP = "birth after a detection gap"
BIRTH_DETECTED = "birth while detected"
FRAGMENT_RETURN = "fragment return"
OTHER = "other"
#: The categories, in the order reports and tables list them.
CATEGORIES = (SWAP, RECOVERY_OTHER, RECOVERY_CLUTTER, BIRTH_GAP, BIRTH_DETECTED, FRAGMENT_RETURN, OTHER)

#: Provenance values in column 1 of the detection rows.
CLUTTER_ID = -1
DISTRACTOR_ID = -2

# Per-row labels of a track's output.
_MATCH, _NEAR, _CLUTTER, _DISTRACTOR = 0, 1, 2, 3


@dataclass(frozen=True)
class IdSwitchEvent:
    """One identity switch: gt object ``gt_id`` moved from ``prev_id`` to ``new_id`` at ``frame``."""

    frame: int
    gt_id: int
    prev_id: int
    new_id: int
    category: str
    reason: str
    #: Last frame the object was matched to ``prev_id`` (before this switch).
    prev_last_match: int
    #: First output row of ``new_id`` (its birth as far as its output tells).
    new_first_frame: int
    #: What ``prev_id`` does at ``frame``: "on gt X", "unmatched", "absent until F", "ended at F".
    prev_fate: str
    sequence: str = ""


@dataclass
class IdSwitchReport:
    """Counts per category (every key of :data:`CATEGORIES`) and the events behind them."""

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(CATEGORIES, 0))
    events: list[IdSwitchEvent] = field(default_factory=list)

    @property
    def total(self) -> int:
        """Number of switches; equals CLEAR's IDSW for the same gt and predictions."""
        return len(self.events)

    def add(self, event: IdSwitchEvent) -> None:
        self.events.append(event)
        self.counts[event.category] += 1


def merge_reports(reports: Iterable[IdSwitchReport]) -> IdSwitchReport:
    """One report for several sequences (counts summed, events concatenated)."""
    merged = IdSwitchReport()
    for report in reports:
        for event in report.events:
            merged.add(event)
    return merged


def format_id_switch_table(reports: Mapping[str, IdSwitchReport], *, title: str = "ID switch cause") -> str:
    """A text table: one row per category (plus the total), one column per tracker, each cell the
    count and its share of that tracker's switches."""
    names = list(reports)
    rows = [[c] + [f"{reports[n].counts[c]}" + _share(reports[n], c) for n in names] for c in CATEGORIES]
    rows.append(["total"] + [str(reports[n].total) for n in names])
    header = [title] + names
    widths = [max(len(str(line[i])) for line in [header, *rows]) for i in range(len(header))]

    def fmt(line: list[str]) -> str:
        return "  ".join(
            [line[0].ljust(widths[0])] + [cell.rjust(width) for cell, width in zip(line[1:], widths[1:])]
        ).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([fmt(header), rule, *[fmt(r) for r in rows[:-1]], rule, fmt(rows[-1])])


def _share(report: IdSwitchReport, category: str) -> str:
    if report.total == 0:
        return ""
    return f" ({100.0 * report.counts[category] / report.total:.0f}%)"


def detection_provenance(
    gt_rows: np.ndarray,
    det_rows: np.ndarray,
    *,
    provenance_iou: float = 0.5,
    target_classes: Iterable[int] = DEFAULT_TARGET_CLASSES,
    distractor_classes: Iterable[int] = DEFAULT_DISTRACTOR_CLASSES,
) -> np.ndarray:
    """The gt object each detection row came from (``-1`` clutter, ``-2`` distractor).

    Column 1 is returned as given unless it is ``-1`` everywhere; then each frame's detections are
    matched one-to-one to all its gt rows (Hungarian on IoU >= ``provenance_iou``): a detection
    matched to a target row gets the target's id, to a distractor row ``-2``, otherwise ``-1``.
    """
    dets = np.asarray(det_rows, dtype=np.float64)
    if dets.size == 0:
        return np.zeros(0, dtype=np.int64)
    if dets.ndim != 2 or dets.shape[1] < 6:
        raise ValueError(f"detections: expected an (N, >=6) MOT array, got shape {dets.shape}")
    given = dets[:, 1].astype(np.int64)
    if np.any(given != CLUTTER_ID):
        return given
    gt = _as_rows(gt_rows, "ground truth")
    targets = np.asarray(sorted(set(int(c) for c in target_classes)), dtype=np.int64)
    distractors = np.asarray(sorted(set(int(c) for c in distractor_classes)), dtype=np.int64)
    out = np.full(len(dets), CLUTTER_ID, dtype=np.int64)
    det_frames = dets[:, 0].astype(np.int64)
    frames = np.unique(det_frames)
    gt_blocks = _group_by_frame(gt, frames)
    for frame, g in zip(frames.tolist(), gt_blocks):
        if len(g) == 0:
            continue
        idx = np.flatnonzero(det_frames == frame)
        iou = box_iou_xywh(g[:, 2:6], dets[idx, 2:6])
        iou[iou < provenance_iou - EPS] = 0
        rows, cols = linear_sum_assignment(-iou)
        ok = iou[rows, cols] > EPS
        classes = g[:, 7].astype(np.int64)
        for r, c in zip(rows[ok].tolist(), cols[ok].tolist()):
            if classes[r] in distractors:
                out[idx[c]] = DISTRACTOR_ID
            elif (classes[r] in targets or classes[r] == -1) and g[r, 6] != 0:
                out[idx[c]] = int(g[r, 1])
    return out


@dataclass
class _History:
    """One track's output rows in frame order: frame, label, gt id (match / near) or -1."""

    frames: list[int] = field(default_factory=list)
    labels: list[int] = field(default_factory=list)
    gts: list[int] = field(default_factory=list)
    matched_gt: dict[int, int] = field(default_factory=dict)


def _nearest(
    pred_box: np.ndarray, boxes: np.ndarray, ids: np.ndarray, near_distance: float
) -> tuple[int, float] | None:
    """Index into ``boxes`` of the nearest box within ``near_distance`` sizes of ``pred_box``."""
    if len(boxes) == 0:
        return None
    centre = pred_box[:2] + pred_box[2:4] / 2
    centres = boxes[:, :2] + boxes[:, 2:4] / 2
    size = np.maximum(np.max(boxes[:, 2:4], axis=1), max(pred_box[2], pred_box[3]))
    dist = np.hypot(*(centres - centre).T) / np.maximum(size, EPS)
    order = np.lexsort((ids, dist))
    best = int(order[0])
    if dist[best] > near_distance:
        return None
    return best, float(dist[best])


def _gap_runs(frames: list[int], detected: set[int], min_gap: int) -> list[tuple[int, int, int]]:
    """Runs ``(first, last, out)`` of at least ``min_gap`` consecutive frames without a detection,
    from the object's first to its last gt frame (``frames``, sorted); ``out`` is how many of them
    the object was not a target in the gt (out of view, or not considered)."""
    if not frames:
        return []
    hits = sorted(f for f in detected if frames[0] <= f <= frames[-1])
    bounds = [frames[0] - 1, *hits, frames[-1] + 1]
    runs = []
    for before, after in zip(bounds[:-1], bounds[1:]):
        if after - before - 1 >= min_gap:
            first, last = before + 1, after - 1
            inside = bisect.bisect_right(frames, last) - bisect.bisect_left(frames, first)
            runs.append((first, last, last - first + 1 - inside))
    return runs


def classify_id_switches(
    gt_rows: np.ndarray,
    pred_rows: np.ndarray,
    det_rows: np.ndarray,
    fps: float,
    iou_threshold: float = 0.5,
    *,
    target_classes: Iterable[int] = DEFAULT_TARGET_CLASSES,
    distractor_classes: Iterable[int] = DEFAULT_DISTRACTOR_CLASSES,
    provenance_iou: float = 0.5,
    min_gap_frames: int = 3,
    lost_gap_frames: int = 1,
    recent_s: float = 1.0,
    near_distance: float = 2.0,
    sequence: str = "",
) -> IdSwitchReport:
    """Every CLEAR identity switch of ``pred_rows`` against ``gt_rows``, classified (module doc).

    ``det_rows`` are the detections the tracker was given (MOT rows; column 1 the provenance, see
    :func:`detection_provenance`); ``fps`` turns ``recent_s`` into frames. ``iou_threshold``,
    ``target_classes`` and ``distractor_classes`` are those of
    :func:`gldt_core.eval.mot_metrics.evaluate_sequence`, whose IDSW equals ``report.total``.
    """
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps}")
    if min_gap_frames < 1 or lost_gap_frames < 1:
        raise ValueError("min_gap_frames and lost_gap_frames must be at least 1")
    recent_frames = max(1, int(round(recent_s * fps)))
    gt = _as_rows(gt_rows, "ground truth")
    pred = _as_rows(pred_rows, "predictions")
    dets = np.asarray(det_rows, dtype=np.float64)
    if dets.size == 0:
        dets = np.zeros((0, 10))
    provenance = detection_provenance(
        gt,
        dets,
        provenance_iou=provenance_iou,
        target_classes=target_classes,
        distractor_classes=distractor_classes,
    )
    detected: dict[int, set[int]] = {}
    for frame, source in zip(dets[:, 0].astype(np.int64).tolist(), provenance.tolist()):
        if source >= 0:
            detected.setdefault(source, set()).add(frame)

    targets = np.asarray(sorted(set(int(c) for c in target_classes)), dtype=np.int64)
    distractors = np.asarray(sorted(set(int(c) for c in distractor_classes)), dtype=np.int64)
    present = np.union1d(gt[:, 0], pred[:, 0]).astype(np.int64)
    histories: dict[int, _History] = {}
    gt_frames: dict[int, list[int]] = {}
    # CLEAR state, as mot_metrics._clear keeps it (original ids instead of relabelled ones).
    prev_id: dict[int, int] = {}
    prev_frame: dict[int, int] = {}
    prev_step: dict[int, int] = {}
    raw_events: list[tuple[int, int, int, int, int]] = []  # frame, gt, prev, new, prev's last match
    for frame, g, p in zip(present.tolist(), _group_by_frame(gt, present), _group_by_frame(pred, present)):
        view = frame_view(frame, g, p, targets, distractors)
        g_ids_all, p_ids_all = view.gt_ids, view.pred_ids
        keep_gt, keep_pred, is_distractor = view.keep_gt, view.keep_pred, view.is_distractor
        g_ids = g_ids_all[keep_gt]
        p_ids = p_ids_all[keep_pred]
        sim = view.similarity[keep_gt][:, keep_pred]
        for gid in g_ids.tolist():
            gt_frames.setdefault(gid, []).append(frame)

        matched: dict[int, int] = {}  # pred id -> gt id
        if len(g_ids) and len(p_ids):
            prev_step_arr = np.array([prev_step.get(i, -1) for i in g_ids.tolist()], dtype=np.int64)
            rows, cols = clear_matches(g_ids, p_ids, prev_step_arr, sim, iou_threshold)
            pairs = list(zip(g_ids[rows].tolist(), p_ids[cols].tolist()))
            for gid, pid in pairs:
                if gid in prev_id and prev_id[gid] != pid:
                    raw_events.append((frame, gid, prev_id[gid], pid, prev_frame[gid]))
                matched[pid] = gid
            prev_step = {}
            for gid, pid in pairs:
                prev_id[gid] = pid
                prev_frame[gid] = frame
                prev_step[gid] = pid

        # Label every output row of this frame.
        target_boxes = g[keep_gt, 2:6]
        distractor_boxes = g[is_distractor, 2:6]
        near_boxes = np.vstack([target_boxes, distractor_boxes])
        near_ids = np.concatenate([g_ids, g_ids_all[is_distractor]])
        for k, pid in enumerate(p_ids_all.tolist()):
            history = histories.setdefault(pid, _History())
            history.frames.append(frame)
            if not keep_pred[k]:
                history.labels.append(_DISTRACTOR)
                history.gts.append(-1)
            elif pid in matched:
                history.labels.append(_MATCH)
                history.gts.append(matched[pid])
                history.matched_gt[frame] = matched[pid]
            else:
                near = _nearest(p[k, 2:6], near_boxes, near_ids, near_distance)
                if near is None:
                    history.labels.append(_CLUTTER)
                    history.gts.append(-1)
                elif near[0] >= len(target_boxes):
                    history.labels.append(_DISTRACTOR)
                    history.gts.append(-1)
                else:
                    history.labels.append(_NEAR)
                    history.gts.append(int(g_ids[near[0]]))

    gaps = {gid: _gap_runs(frames, detected.get(gid, set()), min_gap_frames) for gid, frames in gt_frames.items()}
    report = IdSwitchReport()
    for frame, gid, prev, new, prev_match in raw_events:
        category, reason = _classify(
            frame, gid, new, prev_match, histories[new], gaps.get(gid, []), recent_frames, lost_gap_frames
        )
        report.add(
            IdSwitchEvent(
                frame=frame,
                gt_id=gid,
                prev_id=prev,
                new_id=new,
                category=category,
                reason=reason,
                prev_last_match=prev_match,
                new_first_frame=histories[new].frames[0],
                prev_fate=_fate(histories[prev], frame),
                sequence=sequence,
            )
        )
    return report


def _fate(history: _History, frame: int) -> str:
    at = bisect.bisect_left(history.frames, frame)
    if at < len(history.frames) and history.frames[at] == frame:
        gid = history.matched_gt.get(frame)
        return f"on gt {gid}" if gid is not None else "unmatched"
    if at < len(history.frames):
        return f"absent until {history.frames[at]}"
    return f"ended at {history.frames[-1]}"


def _classify(
    frame: int,
    gid: int,
    new: int,
    prev_match: int,
    history: _History,
    gaps: list[tuple[int, int, int]],
    recent_frames: int,
    lost_gap_frames: int,
) -> tuple[str, str]:
    before = bisect.bisect_left(history.frames, frame)  # rows strictly before the switch
    i = before - 1
    while i >= 0 and history.labels[i] == _NEAR and history.gts[i] == gid:
        i -= 1
    arrived = history.frames[i + 1] if i + 1 < before else frame
    if i >= 0 and history.labels[i] == _MATCH and history.gts[i] == gid:
        return FRAGMENT_RETURN, f"id {new} held gt {gid} until frame {history.frames[i]}"
    if frame - arrived > recent_frames:
        return OTHER, f"id {new} followed gt {gid} unmatched from frame {arrived}"
    if i < 0:
        born = arrived
        for first, last, out in gaps:
            if last > prev_match and first <= frame and born >= first:
                where = f" ({out} out of the gt)" if out else ""
                return BIRTH_GAP, f"gt {gid} undetected {first}-{last}{where}, id {new} born {born}"
        return BIRTH_DETECTED, f"id {new} born {born}, gt detected after last match {prev_match}"
    label, source, since = history.labels[i], history.gts[i], history.frames[i]
    if label in (_CLUTTER, _DISTRACTOR):
        what = "clutter" if label == _CLUTTER else "a distractor"
        return RECOVERY_CLUTTER, f"id {new} was on {what} until frame {since}"
    seen = history.frames[i:before] + [frame]
    hole = max(b - a - 1 for a, b in zip(seen[:-1], seen[1:]))
    if hole >= lost_gap_frames:
        return RECOVERY_OTHER, f"id {new} left gt {source} at {since}, lost {hole} frames"
    return SWAP, f"id {new} was on gt {source} at frame {since}"
