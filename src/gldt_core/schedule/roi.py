"""ROI manager: where the local detector looks, as pure functions of track predictions.

The paper (Methods, "Local Detection") builds a 300x300 window centred on each Kalman-predicted
target, merges windows that overlap by more than ``tau_o``, expands a window that holds several
targets while they drift apart, splits it once they are more than ``tau_d`` pixels apart, and
keeps every target inside the central "safe zone" covering ``tau_s`` of the window's area.

Everything here is a pure function of its arguments (no hidden state) so the same code runs in
the offline GL-DT system and in the ROS scheduler node, and so it can be tested on geometry alone.
The only memory the rules need - which targets shared a window last frame, so a shared window
is expanded instead of dropped when they separate - is passed in and returned explicitly as
``groups`` (tuples of track ids).

Conventions and decisions:

* Boxes and ROIs are ``[x1, y1, x2, y2]`` pixels; an ROI is a crop ``frame[y1:y2, x1:x2]``, so
  ``x2 - x1`` is its width and a clipped ROI satisfies ``0 <= x1 < x2 <= frame_width``.
* "Overlap" (for ``tau_o``) is **intersection over the smaller area**, not IoU. A default window
  fully inside an expanded one is pure redundancy, yet its IoU with the big one can be far below
  0.2; intersection-over-smaller calls it 1.0 and merges it. For two windows of the same size the
  two measures rank pairs identically.
* "Distance between targets" (for ``tau_d``) is the Euclidean distance between box centres, and a
  group's spread is its largest pairwise distance.
* Safe zone: the central rectangle with each side scaled by ``sqrt(tau_s)`` (so its area is
  ``tau_s`` of the ROI's). A window is made just large enough (never below ``roi_size``) that the
  bounding box of its targets fits in its safe zone. Its edges are then rounded outwards to whole
  pixels, so a window whose centre is not a whole pixel is ``roi_size + 1`` wide. Why not exactly
  ``roi_size``: rounding the centre instead moves the crop by up to half a pixel, and the local
  detector's boxes on 3-5 px drones depend on the crop's sub-pixel placement, enough to change
  the tracking scores of a whole scene (``docs/experiment-log.md``); the shipped layout is the
  one the results were measured with.
* Frame edges: a window is shifted (not shrunk) to lie inside the frame, so a target at the edge
  still gets a full-size window; the safe zone then cannot be honoured on the edge side - there is
  nothing to see beyond the frame. A frame smaller than the window gives a window of frame size.
  Overlaps for merging are taken between the windows as clipped, the crops the local detector
  will actually see: shifting windows into a small frame, or near its edges, can pile them onto
  each other, and merging before clipping left duplicate crops.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

#: Table I defaults.
DEFAULT_ROI_SIZE = 300
DEFAULT_TAU_OVERLAP = 0.2
DEFAULT_TAU_DISTANCE = 700.0
DEFAULT_TAU_SAFE = 0.8


#: Table I's pixel sizes are for 1080-line frames.
REFERENCE_HEIGHT = 1080.0
#: Smallest ROI side a scaled Table I gives (the local detector needs some context around a target).
MIN_SCALED_ROI = 96


@dataclass(frozen=True)
class RoiParams:
    """Geometry thresholds of the ROI manager (paper Table I).

    ``roi_size`` and ``tau_distance`` are pixels of a ``reference_height``-line frame (Table I's
    1080); :meth:`at_resolution` scales them to the frame at hand, so that an ROI covers the same
    share of a 640x512 frame as of a 1080p one. ``reference_height`` None takes them as pixels of
    every frame.
    """

    roi_size: int = DEFAULT_ROI_SIZE
    tau_overlap: float = DEFAULT_TAU_OVERLAP
    tau_distance: float = DEFAULT_TAU_DISTANCE
    tau_safe: float = DEFAULT_TAU_SAFE
    reference_height: float | None = REFERENCE_HEIGHT

    def at_resolution(self, frame_height: int) -> RoiParams:
        """These parameters in pixels of a frame ``frame_height`` lines high."""
        if self.reference_height is None or frame_height == self.reference_height:
            return self
        scale = float(frame_height) / float(self.reference_height)
        return RoiParams(
            roi_size=max(MIN_SCALED_ROI, int(round(self.roi_size * scale))),
            tau_overlap=self.tau_overlap,
            tau_distance=self.tau_distance * scale,
            tau_safe=self.tau_safe,
            reference_height=None,
        )

    def __post_init__(self) -> None:
        if not (isinstance(self.roi_size, (int, np.integer)) and self.roi_size >= 16):
            raise ValueError(f"roi_size must be an integer >= 16 pixels, got {self.roi_size!r}")
        if not 0.0 <= self.tau_overlap <= 1.0:
            raise ValueError(f"tau_overlap must be in [0, 1], got {self.tau_overlap!r}")
        if not (math.isfinite(self.tau_distance) and self.tau_distance > 0):
            raise ValueError(f"tau_distance must be a positive number of pixels, got {self.tau_distance!r}")
        if not 0.0 < self.tau_safe <= 1.0:
            raise ValueError(f"tau_safe must be in (0, 1], got {self.tau_safe!r}")
        if self.reference_height is not None and not (
            isinstance(self.reference_height, (int, float))
            and math.isfinite(self.reference_height)
            and self.reference_height > 0
        ):
            raise ValueError(
                f"reference_height must be a positive number of lines or None, got {self.reference_height!r}"
            )


@dataclass(frozen=True)
class RoiLayout:
    """The windows for one frame.

    ``rois`` is ``(R, 4)`` int64 ``[x1, y1, x2, y2]`` clipped to the frame; ``groups[r]`` holds the
    track ids inside ``rois[r]``. Pass ``groups`` back into :func:`plan_rois` next frame.
    """

    rois: np.ndarray
    groups: tuple[tuple[int, ...], ...]

    def __len__(self) -> int:
        return int(self.rois.shape[0])


EMPTY_LAYOUT = RoiLayout(rois=np.zeros((0, 4), dtype=np.int64), groups=())


def box_centres(boxes: np.ndarray) -> np.ndarray:
    """Centres ``(N, 2)`` of ``(N, >=4)`` xyxy boxes."""
    boxes = np.asarray(boxes, dtype=np.float64)
    return np.stack([(boxes[:, 0] + boxes[:, 2]) * 0.5, (boxes[:, 1] + boxes[:, 3]) * 0.5], axis=1)


def box_area(box: Sequence[float]) -> float:
    """Area of one xyxy box (0 for an empty box)."""
    return max(0.0, float(box[2]) - float(box[0])) * max(0.0, float(box[3]) - float(box[1]))


def roi_overlap(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over the smaller of the two areas (see module docstring for why not IoU)."""
    ix = min(float(a[2]), float(b[2])) - max(float(a[0]), float(b[0]))
    iy = min(float(a[3]), float(b[3])) - max(float(a[1]), float(b[1]))
    if ix <= 0.0 or iy <= 0.0:
        return 0.0
    smaller = min(box_area(a), box_area(b))
    return (ix * iy) / smaller if smaller > 0.0 else 0.0


def overlap_matrix(rois: np.ndarray) -> np.ndarray:
    """:func:`roi_overlap` of every pair of ``(R, 4)`` windows, as an ``(R, R)`` array."""
    rois = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
    x1, y1, x2, y2 = rois.T
    ix = np.minimum(x2[:, None], x2[None, :]) - np.maximum(x1[:, None], x1[None, :])
    iy = np.minimum(y2[:, None], y2[None, :]) - np.maximum(y1[:, None], y1[None, :])
    intersection = np.where((ix > 0.0) & (iy > 0.0), ix * iy, 0.0)
    area = np.maximum(x2 - x1, 0.0) * np.maximum(y2 - y1, 0.0)
    smaller = np.minimum(area[:, None], area[None, :])
    return np.divide(intersection, smaller, out=np.zeros_like(intersection), where=smaller > 0.0)


def safe_zone(roi: Sequence[float], tau_safe: float) -> np.ndarray:
    """Central rectangle of ``roi`` covering ``tau_safe`` of its area (each side scaled by sqrt)."""
    scale = math.sqrt(tau_safe)
    cx, cy = (roi[0] + roi[2]) * 0.5, (roi[1] + roi[3]) * 0.5
    half_w, half_h = (roi[2] - roi[0]) * 0.5 * scale, (roi[3] - roi[1]) * 0.5 * scale
    return np.array([cx - half_w, cy - half_h, cx + half_w, cy + half_h], dtype=np.float64)


def roi_for_boxes(boxes: np.ndarray, params: RoiParams) -> np.ndarray:
    """Smallest window (>= ``roi_size`` a side) centred on ``boxes`` whose safe zone holds them all.

    Returned as float ``[x1, y1, x2, y2]``, not yet clipped to a frame.
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    x1, y1 = boxes[:, 0].min(), boxes[:, 1].min()
    x2, y2 = boxes[:, 2].max(), boxes[:, 3].max()
    scale = math.sqrt(params.tau_safe)
    width = max(float(params.roi_size), (x2 - x1) / scale)
    height = max(float(params.roi_size), (y2 - y1) / scale)
    cx, cy = (x1 + x2) * 0.5, (y1 + y2) * 0.5
    return np.array([cx - width / 2, cy - height / 2, cx + width / 2, cy + height / 2])


def clip_roi(roi: Sequence[float] | np.ndarray, frame_size: tuple[int, int]) -> np.ndarray:
    """Integer window inside a ``(width, height)`` frame, shifted rather than shrunk when possible.

    Edges are rounded outwards to whole pixels, so the window never gets smaller than asked;
    it is only cut where the frame itself is smaller.
    """
    frame_w, frame_h = int(frame_size[0]), int(frame_size[1])
    if frame_w <= 0 or frame_h <= 0:
        raise ValueError(f"frame size must be positive, got {frame_size!r}")
    out = np.empty(4, dtype=np.int64)
    for axis, limit in ((0, frame_w), (1, frame_h)):
        lo, hi = float(roi[axis]), float(roi[axis + 2])
        # Outward rounding keeps everything the float window held (the safe zone included).
        start, end = int(math.floor(lo + 1e-9)), int(math.ceil(hi - 1e-9))
        length = max(1, end - start)
        if length > limit:
            length = limit
            start = int(round((lo + hi) * 0.5 - length * 0.5))
        start = min(max(start, 0), limit - length)
        out[axis], out[axis + 2] = start, start + length
    return out


def _split_until_within(members: list[int], centres: dict[int, np.ndarray], tau_distance: float) -> list[list[int]]:
    """Split a group whose spread exceeds ``tau_distance`` around its two farthest members.

    Each member joins the nearer of the two extremes; recurse until every part is compact.
    Deterministic for a given member order (ties go to the first extreme).
    """
    if len(members) < 2:
        return [members]
    pts = np.array([centres[m] for m in members])
    diff = pts[:, None, :] - pts[None, :, :]
    dist = np.sqrt((diff**2).sum(axis=2))
    i, j = np.unravel_index(int(np.argmax(dist)), dist.shape)
    if dist[i, j] <= tau_distance:
        return [members]
    to_i = np.linalg.norm(pts - pts[i], axis=1) <= np.linalg.norm(pts - pts[j], axis=1)
    first = [m for m, keep in zip(members, to_i) if keep]
    second = [m for m, keep in zip(members, to_i) if not keep]
    return _split_until_within(first, centres, tau_distance) + _split_until_within(second, centres, tau_distance)


def plan_rois(
    boxes: np.ndarray,
    track_ids: Iterable[int] | None,
    frame_size: tuple[int, int],
    params: RoiParams = RoiParams(),
    previous_groups: Sequence[Sequence[int]] = (),
) -> RoiLayout:
    """Windows for one frame from predicted target boxes.

    ``boxes``: ``(K, 4)`` predicted xyxy boxes; ``track_ids``: their ids (``None``: 0..K-1, no
    memory); ``frame_size``: ``(width, height)``; ``previous_groups``: ``RoiLayout.groups`` of the
    previous frame, so targets that shared a window keep sharing it (expanded) until they are
    more than ``tau_distance`` apart.

    Steps: (1) carry over last frame's groups for ids still present, new ids alone; (2) split any
    group spread over more than ``tau_distance``; (3) merge groups whose windows overlap by more
    than ``tau_overlap`` unless the merged group would be spread over more than ``tau_distance``
    (it would be split again next frame - the guard stops that flip-flop); (4) size each window so
    its targets sit in its safe zone and clip it to the frame.
    """
    boxes = np.asarray(boxes, dtype=np.float64)
    if boxes.size == 0:
        return EMPTY_LAYOUT
    if boxes.ndim != 2 or boxes.shape[1] < 4:
        raise ValueError(f"plan_rois: boxes must be (K, 4) xyxy, got shape {boxes.shape}")
    boxes = boxes[:, :4]
    if not np.all(np.isfinite(boxes)):
        raise ValueError("plan_rois: predicted boxes contain NaN or infinite coordinates")
    ids = list(range(len(boxes))) if track_ids is None else [int(i) for i in track_ids]
    if len(ids) != len(boxes):
        raise ValueError(f"plan_rois: {len(boxes)} boxes but {len(ids)} track ids")
    if len(set(ids)) != len(ids):
        raise ValueError(f"plan_rois: duplicate track ids {sorted(ids)}")
    box_of = {i: boxes[k] for k, i in enumerate(ids)}
    centre_of = {i: c for i, c in zip(ids, box_centres(boxes))}

    # (1) carry over previous groups, restricted to ids still present.
    groups: list[list[int]] = []
    seen: set[int] = set()
    for old in previous_groups:
        kept = [int(i) for i in old if int(i) in box_of and int(i) not in seen]
        if kept:
            groups.append(kept)
            seen.update(kept)
    groups.extend([i] for i in ids if i not in seen)

    # (2) split groups whose targets drifted more than tau_distance apart.
    split: list[list[int]] = []
    for group in groups:
        split.extend(_split_until_within(group, centre_of, params.tau_distance))
    groups = split

    # (3) merge overlapping windows (greedy, most-overlapping pair first, until stable), compared
    # as clipped to the frame: those are the crops, and clipping can pile windows onto each other.
    index_of = {i: k for k, i in enumerate(ids)}
    centres = np.array([centre_of[i] for i in ids])
    distance = np.sqrt(((centres[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2))

    def window(group: list[int]) -> np.ndarray:
        return clip_roi(roi_for_boxes(np.array([box_of[i] for i in group]), params), frame_size)

    def spread(group: list[int]) -> float:
        members = [index_of[i] for i in group]
        return float(distance[np.ix_(members, members)].max())

    windows = [window(g) for g in groups]
    while len(groups) > 1:
        overlap = np.triu(overlap_matrix(np.array(windows, dtype=np.float64)), k=1)
        candidates = np.flatnonzero(overlap > params.tau_overlap)
        # Most overlapping pair first; equal overlaps in (a, b) order, as a double loop finds them.
        candidates = candidates[np.argsort(-overlap.flat[candidates], kind="stable")]
        best: tuple[int, int] | None = None
        for flat in candidates:
            a, b = divmod(int(flat), len(groups))
            if spread(groups[a] + groups[b]) <= params.tau_distance:
                best = (a, b)
                break
        if best is None:
            break
        a, b = best
        groups[a] = groups[a] + groups[b]
        windows[a] = window(groups[a])
        del groups[b], windows[b]

    # (4) order windows by their smallest id so the layout is deterministic.
    order = sorted(range(len(groups)), key=lambda k: min(groups[k]))
    rois = np.array([windows[k] for k in order], dtype=np.int64).reshape(-1, 4)
    return RoiLayout(rois=rois, groups=tuple(tuple(sorted(groups[k])) for k in order))


def roi_of_each_box(boxes: np.ndarray, rois: np.ndarray) -> np.ndarray:
    """Index of the ROI containing each box's centre (-1 if none); used to count per-ROI hits."""
    centres = box_centres(np.asarray(boxes, dtype=np.float64).reshape(-1, 4))
    rois = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
    out = np.full(len(centres), -1, dtype=np.int64)
    for r, roi in enumerate(rois):
        inside = (
            (out < 0)
            & (centres[:, 0] >= roi[0])
            & (centres[:, 0] < roi[2])
            & (centres[:, 1] >= roi[1])
            & (centres[:, 1] < roi[3])
        )
        out[inside] = r
    return out
