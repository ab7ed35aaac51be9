"""Detection streams made from ground truth, with the failure modes a real detector has.

Used by ``gldt bench tracking`` to compare trackers "at equal detections": every tracker sees the
same stream. A stream is deterministic for a seed and models

* **misses in bursts** (occlusion by clouds, a drone behind a tree line, detector blind spots):
  per object a two-state Markov chain enters a miss burst with probability ``burst_rate`` per
  frame and stays in it for a uniformly drawn ``burst_frames`` length; ground-truth visibility
  below ``min_visibility`` is always a miss; plus independent misses at ``miss_rate``;
* **scores**: a fraction ``low_score_rate`` of true detections get a score in ``low_score`` (the
  band ByteTrack's second stage exists for), the rest in ``high_score``; or, with ``score_beta``
  set, every true detection's score is drawn from that Beta distribution (a wide spread);
* **box jitter**: centre noise with standard deviation ``jitter_frac`` of the box size (plus
  ``jitter_px``), size noise ``size_jitter_frac``;
* **false positives**: Poisson(``fp_rate``) clutter boxes per frame of target-like size anywhere
  in the image (independent from frame to frame), distractors (birds, class 2-4 in the gt)
  detected with ``distractor_rate``, and **persistent clutter** (``clutter_tracks_rate`` births
  per frame): false objects that live ``clutter_tracks_frames`` frames and move like a target
  (``clutter_tracks_speed`` px per frame, slowly turning), detected on a fraction
  ``clutter_tracks_detect`` of their frames with a score around a level of their own.

Output rows are MOTChallenge det lines ``frame, source, x, y, w, h, score, -1, -1, -1`` where
``source`` is the provenance of the detection: the gt id of the object it was made from, ``-1``
for clutter (independent or persistent) and ``-2`` for a detected distractor. Trackers never read
that column (:func:`gldt_core.track.runner.track_detection_rows` uses frame, box and score);
evaluation tools may (identity-switch classification).

:class:`StreamProfile` bundles a ground-truth generator, a frame rate, a failure model and an
optional camera ego-motion (:class:`EgoMotion`, applied to gt and detections alike);
:data:`PROFILES` are the benchmark's profiles, some for tuning and the rest held out
(:func:`profile_sequences` builds their sequences). :func:`crossing_multi_target_gt` makes
multi-target ground truth in which targets cross and occlude each other.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Provenance (column 1) of clutter detections and of detected distractors.
CLUTTER_SOURCE = -1
DISTRACTOR_SOURCE = -2
#: Frame rate the per-frame fields of :class:`StreamParams` are stated at (see :meth:`StreamParams.at_fps`).
REFERENCE_FPS = 30.0


@dataclass(frozen=True)
class StreamParams:
    """Detector failure model; defaults give a hard but realistic small-drone stream.

    The new kinds of failure (``score_beta``, persistent clutter) are off by default, so the
    default stream is the model the trackers' defaults were tuned on.
    """

    burst_rate: float = 0.015
    burst_frames: tuple[int, int] = (8, 60)
    miss_rate: float = 0.05
    min_visibility: float = 0.25
    low_score_rate: float = 0.2
    low_score: tuple[float, float] = (0.15, 0.5)
    high_score: tuple[float, float] = (0.55, 0.95)
    score_beta: tuple[float, float] | None = None
    jitter_frac: float = 0.08
    jitter_px: float = 0.5
    size_jitter_frac: float = 0.08
    fp_rate: float = 0.3
    fp_score: tuple[float, float] = (0.2, 0.7)
    distractor_rate: float = 0.5
    target_classes: tuple[int, ...] = (1,)
    clutter_tracks_rate: float = 0.0
    clutter_tracks_frames: tuple[int, int] = (60, 300)
    clutter_tracks_speed: tuple[float, float] = (1.5, 8.0)
    clutter_tracks_detect: float = 0.85
    clutter_tracks_score: tuple[float, float] = (0.3, 0.85)

    def at_fps(self, fps: float, reference: float = REFERENCE_FPS) -> StreamParams:
        """These parameters, stated per frame at ``reference`` Hz, for a stream at ``fps``.

        What lasts or happens in time is rescaled (miss bursts and their rate, persistent
        clutter's births, life and speed in px per frame) so a profile means the same seconds at
        any frame rate; what a detector does per frame (independent misses and clutter, jitter,
        scores) is not.
        """
        if not np.isfinite(fps) or fps <= 0:
            raise ValueError(f"fps must be a positive number, got {fps}")
        k = fps / reference

        def frames(span: tuple[int, int]) -> tuple[int, int]:
            low = max(1, round(span[0] * k))
            return low, max(low, round(span[1] * k))

        return dataclasses.replace(
            self,
            burst_rate=self.burst_rate / k,
            burst_frames=frames(self.burst_frames),
            clutter_tracks_rate=self.clutter_tracks_rate / k,
            clutter_tracks_frames=frames(self.clutter_tracks_frames),
            clutter_tracks_speed=(self.clutter_tracks_speed[0] / k, self.clutter_tracks_speed[1] / k),
        )


def detections_from_gt(
    gt: np.ndarray,
    seed: int,
    image_size: tuple[int, int],
    params: StreamParams | None = None,
    num_frames: int | None = None,
) -> np.ndarray:
    """A detection stream ``(N, 10)`` for gt rows ``(N, 10)`` (see the module doc)."""
    p = params or StreamParams()
    rng = np.random.default_rng(seed)
    gt = np.asarray(gt, dtype=np.float64)
    if num_frames is None:
        num_frames = int(gt[:, 0].max(initial=0))
    width, height = image_size
    rows: list[np.ndarray] = []
    classes = gt[:, 7].astype(int)
    is_target = np.isin(classes, p.target_classes) | (classes == -1)
    # Burst state per object: frames of miss left.
    burst_left: dict[tuple[int, int], int] = {}
    order = np.argsort(gt[:, 0], kind="stable")
    gt = gt[order]
    is_target = is_target[order]
    sizes = gt[is_target][:, 4:6]
    typical = np.median(sizes, axis=0) if len(sizes) else np.array([20.0, 15.0])
    frame_col = gt[:, 0].astype(int)
    starts = np.searchsorted(frame_col, np.arange(1, num_frames + 2))
    # Persistent clutter draws from its own generator: the rest of the stream is the same with or without it.
    persistent = _persistent_clutter(np.random.default_rng([seed, 1]), num_frames, image_size, typical, p)
    for f in range(1, num_frames + 1):
        block = gt[starts[f - 1] : starts[f]]
        target = is_target[starts[f - 1] : starts[f]]
        for row, tgt in zip(block, target):
            key = (int(row[1]), int(tgt))
            if not tgt:
                if rng.random() < p.distractor_rate:
                    rows.append(_jittered(row, f, rng.uniform(*p.fp_score), p, rng, DISTRACTOR_SOURCE))
                continue
            left = burst_left.get(key, 0)
            if left > 0:
                burst_left[key] = left - 1
                continue
            if rng.random() < p.burst_rate:
                burst_left[key] = int(rng.integers(p.burst_frames[0], p.burst_frames[1] + 1)) - 1
                continue
            visibility = row[8] if row[8] >= 0 else 1.0
            if visibility < p.min_visibility or rng.random() < p.miss_rate:
                continue
            if p.score_beta is not None:
                score = float(np.clip(rng.beta(*p.score_beta), 0.01, 0.99))
            else:
                band = p.low_score if rng.random() < p.low_score_rate else p.high_score
                score = rng.uniform(*band)
            rows.append(_jittered(row, f, score, p, rng, int(row[1])))
        for _ in range(rng.poisson(p.fp_rate)):
            w, h = typical * rng.uniform(0.6, 1.6, 2)
            x, y = rng.uniform(0, width - w), rng.uniform(0, height - h)
            rows.append(np.array([f, CLUTTER_SOURCE, x, y, w, h, rng.uniform(*p.fp_score), -1, -1, -1]))
        rows.extend(persistent.get(f, ()))
    if not rows:
        return np.zeros((0, 10))
    return np.vstack(rows)


def _jittered(
    row: np.ndarray, frame: int, score: float, p: StreamParams, rng: np.random.Generator, source: int
) -> np.ndarray:
    w, h = row[4], row[5]
    size = 0.5 * (w + h)
    cx = row[2] + w / 2 + rng.normal(0, p.jitter_frac * size + p.jitter_px)
    cy = row[3] + h / 2 + rng.normal(0, p.jitter_frac * size + p.jitter_px)
    w2 = max(1.0, w * (1 + rng.normal(0, p.size_jitter_frac)))
    h2 = max(1.0, h * (1 + rng.normal(0, p.size_jitter_frac)))
    return np.array([frame, source, cx - w2 / 2, cy - h2 / 2, w2, h2, score, -1, -1, -1])


def _persistent_clutter(
    rng: np.random.Generator, num_frames: int, image_size: tuple[int, int], typical: np.ndarray, p: StreamParams
) -> dict[int, list[np.ndarray]]:
    """``{frame: [det rows]}`` of the false objects that persist and move like targets."""
    out: dict[int, list[np.ndarray]] = {}
    if p.clutter_tracks_rate <= 0:
        return out
    width, height = image_size
    for birth in range(1, num_frames + 1):
        for _ in range(rng.poisson(p.clutter_tracks_rate)):
            life = int(rng.integers(p.clutter_tracks_frames[0], p.clutter_tracks_frames[1] + 1))
            w, h = typical * rng.uniform(0.6, 1.6, 2)
            pos = rng.uniform([0.0, 0.0], [max(1.0, width - w), max(1.0, height - h)])
            speed = rng.uniform(*p.clutter_tracks_speed)
            heading = rng.uniform(-np.pi, np.pi)
            turn = rng.normal(0, 0.02)  # rad per frame
            level = rng.uniform(*p.clutter_tracks_score)
            for f in range(birth, min(num_frames, birth + life - 1) + 1):
                if f > birth:
                    if rng.random() < 0.03:
                        turn = rng.normal(0, 0.02)
                    heading += turn
                    pos = pos + speed * np.array([np.cos(heading), np.sin(heading)])
                    if not 0 <= pos[0] <= width - w:
                        heading = np.pi - heading
                        pos[0] = np.clip(pos[0], 0, width - w)
                    if not 0 <= pos[1] <= height - h:
                        heading = -heading
                        pos[1] = np.clip(pos[1], 0, height - h)
                if rng.random() >= p.clutter_tracks_detect:
                    continue
                score = float(np.clip(level + rng.normal(0, 0.05), 0.01, 0.99))
                row = np.array([f, CLUTTER_SOURCE, pos[0], pos[1], w, h, 1, -1, 1, -1], dtype=np.float64)
                out.setdefault(f, []).append(_jittered(row, f, score, p, rng, CLUTTER_SOURCE))
    return out


def simple_multi_target_gt(
    seed: int, frames: int, size: tuple[int, int] = (1920, 1080), targets: int = 3, fps: float = 30.0
) -> np.ndarray:
    """A plain multi-target motion generator (fallback when :mod:`gldt_core.sim` is unavailable).

    Targets of 8-40 px fly at 60-450 px/s with slowly turning headings (random turn rate, changed
    every second or so) and bounce off the image border; all are class 1, fully visible.
    Returns MOT gt rows ``(N, 10)``.
    """
    rng = np.random.default_rng(seed)
    width, height = size
    rows = []
    for target in range(targets):
        span = rng.uniform(8, 40)
        w, h = span, span * rng.uniform(0.4, 0.9)
        pos = rng.uniform([w, h], [width - 2 * w, height - 2 * h])
        speed = rng.uniform(60, 450)
        heading = rng.uniform(-np.pi, np.pi)
        turn = 0.0
        for f in range(1, frames + 1):
            if rng.random() < 1.0 / fps:
                turn = rng.normal(0, 1.0)  # rad/s
            heading += turn / fps
            pos = pos + speed / fps * np.array([np.cos(heading), np.sin(heading)])
            if not 0 <= pos[0] <= width - w:
                heading = np.pi - heading
                pos[0] = np.clip(pos[0], 0, width - w)
            if not 0 <= pos[1] <= height - h:
                heading = -heading
                pos[1] = np.clip(pos[1], 0, height - h)
            rows.append([f, target + 1, pos[0], pos[1], w, h, 1, 1, 1, -1])
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 10)
    return table[np.argsort(table[:, 0], kind="stable")]


# --------------------------------------------------------------------------------- crossings
def crossing_multi_target_gt(
    seed: int,
    frames: int,
    size: tuple[int, int] = (1920, 1080),
    targets: int = 3,
    fps: float = 30.0,
    target_size: tuple[float, float] = (10.0, 45.0),
    speed: tuple[float, float] = (40.0, 260.0),
) -> np.ndarray:
    """Multi-target ground truth in which the targets cross and occlude each other.

    The targets are paired; each pair meets at a point of the central part of the image at a
    time in the middle half of the sequence, flying on headings 25-155 degrees apart (so they
    pass through each other rather than touch); an odd target out passes the first pair's
    meeting point 0.2-0.8 s after it. Paths are straight lines plus a lateral weave (zero at the
    meeting), at 40-260 px/s (kept slow enough, where possible, to stay in view from start to
    end); sizes (span 10-45 px at 1080p, scaled with the image height) grow or shrink slowly as a
    target approaches or recedes. The larger target is the nearer one: where boxes overlap, the
    farther target's visibility (column 8) drops by the covered fraction of its box, times the
    fraction of it inside the view. Positions are a function of time ``t = (frame - 1) / fps``,
    so the same seed at another frame rate samples the same trajectories. Class 1, ids
    1..targets; rows only where a box overlaps the view.
    """
    if targets < 1 or frames < 1:
        raise ValueError(f"targets and frames must be >= 1, got {targets}, {frames}")
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive number, got {fps}")
    rng = np.random.default_rng(seed)
    width, height = size
    scale = height / 1080.0
    duration = max(frames - 1, 1) / fps
    t = np.arange(frames) / fps
    order = rng.permutation(targets)
    groups = [list(order[i : i + 2]) for i in range(0, targets - targets % 2, 2)] or [[order[0]]]
    if targets % 2 and targets > 1:
        groups[0].append(order[-1])
    centres = np.zeros((targets, frames, 2))
    spans = np.zeros((targets, frames))
    aspect = np.zeros(targets)
    for group in groups:
        meet = rng.uniform([0.25 * width, 0.25 * height], [0.75 * width, 0.75 * height])
        t_meet = rng.uniform(0.25, 0.75) * duration
        first_heading = rng.uniform(-np.pi, np.pi)
        for rank, target in enumerate(group):
            if rank == 0:
                heading, t_pass = first_heading, t_meet
            else:
                heading = first_heading + rng.choice([-1.0, 1.0]) * np.radians(rng.uniform(25.0, 155.0))
                t_pass = t_meet if rank == 1 else t_meet + rng.uniform(0.2, 0.8)
            direction = np.array([np.cos(heading), np.sin(heading)])
            fastest = min(
                _ray_to_border(meet, direction, size) / max(duration - t_pass, 1e-6),
                _ray_to_border(meet, -direction, size) / max(t_pass, 1e-6),
            )
            target_speed = float(np.clip(rng.uniform(*speed), speed[0], max(speed[0], fastest)))
            amplitude = rng.uniform(0.0, 40.0) * scale
            omega = rng.uniform(0.5, 1.5)
            normal = np.array([-direction[1], direction[0]])
            lateral = amplitude * np.sin(omega * (t - t_pass))
            centres[target] = meet + np.outer(target_speed * (t - t_pass), direction) + np.outer(lateral, normal)
            growth = rng.uniform(-0.08, 0.08)  # per second: approaching or receding
            spans[target] = rng.uniform(*target_size) * scale * np.exp(growth * (t - t_pass))
            aspect[target] = rng.uniform(0.45, 0.9)
    widths, heights = spans, spans * aspect[:, None]
    boxes = np.stack(
        [
            centres[..., 0] - widths / 2,
            centres[..., 1] - heights / 2,
            centres[..., 0] + widths / 2,
            centres[..., 1] + heights / 2,
        ],
        axis=-1,
    )  # (targets, frames, 4) x1 y1 x2 y2 unclipped
    clipped = boxes.copy()
    clipped[..., [0, 2]] = np.clip(boxes[..., [0, 2]], 0, width)
    clipped[..., [1, 3]] = np.clip(boxes[..., [1, 3]], 0, height)
    area = (boxes[..., 2] - boxes[..., 0]) * (boxes[..., 3] - boxes[..., 1])
    inside = np.clip(clipped[..., 2] - clipped[..., 0], 0, None) * np.clip(clipped[..., 3] - clipped[..., 1], 0, None)
    covered = np.zeros((targets, frames))
    nearness = spans.mean(axis=1)
    for a in range(targets):
        for b in range(targets):
            if nearness[b] > nearness[a] or (nearness[b] == nearness[a] and b < a):  # b in front of a
                ix = np.clip(
                    np.minimum(clipped[a, :, 2], clipped[b, :, 2]) - np.maximum(clipped[a, :, 0], clipped[b, :, 0]),
                    0,
                    None,
                )
                iy = np.clip(
                    np.minimum(clipped[a, :, 3], clipped[b, :, 3]) - np.maximum(clipped[a, :, 1], clipped[b, :, 1]),
                    0,
                    None,
                )
                covered[a] += ix * iy
    rows = []
    for target in range(targets):
        for k in np.flatnonzero(inside[target] > 0):
            x1, y1, x2, y2 = clipped[target, k]
            visibility = inside[target, k] / area[target, k] * max(0.0, 1.0 - covered[target, k] / inside[target, k])
            rows.append([k + 1, target + 1, x1, y1, x2 - x1, y2 - y1, 1, 1, visibility, -1])
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 10)
    return table[np.lexsort((table[:, 1], table[:, 0]))]


def _ray_to_border(point: np.ndarray, direction: np.ndarray, size: tuple[int, int]) -> float:
    """Distance from ``point`` (inside the image) along ``direction`` to the image border."""
    limits = []
    for axis, extent in enumerate(size):
        if direction[axis] > 1e-9:
            limits.append((extent - point[axis]) / direction[axis])
        elif direction[axis] < -1e-9:
            limits.append(-point[axis] / direction[axis])
    return float(min(limits)) if limits else float("inf")


# --------------------------------------------------------------------------------- ego-motion
@dataclass(frozen=True)
class EgoMotion:
    """Camera ego-motion as a global image translation and rotation (about the image centre).

    The pan velocity is a random walk (Ornstein-Uhlenbeck: stationary spread ``pan_speed`` px/s,
    correlation time ``pan_time`` s) integrated into an offset that drifts back to the centre
    with time constant ``pan_return`` s; the roll angle is a random walk of spread ``roll_deg``
    and correlation time ``roll_time`` s. All in seconds: the same motion at any frame rate.
    """

    pan_speed: float = 150.0
    pan_time: float = 1.5
    pan_return: float = 4.0
    roll_deg: float = 1.5
    roll_time: float = 2.0


def ego_motion_path(seed: int, frames: int, fps: float, motion: EgoMotion) -> np.ndarray:
    """``(frames, 3)`` ``[dx, dy, angle_rad]`` of frames 1..frames (frame 1: no motion yet)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / fps
    a_pan, a_roll = np.exp(-dt / motion.pan_time), np.exp(-dt / motion.roll_time)
    back = np.exp(-dt / motion.pan_return)
    roll_sd = np.radians(motion.roll_deg)
    path = np.zeros((frames, 3))
    velocity = rng.normal(0.0, motion.pan_speed, 2)
    offset, angle = np.zeros(2), 0.0
    for k in range(1, frames):
        velocity = a_pan * velocity + np.sqrt(1 - a_pan**2) * rng.normal(0.0, motion.pan_speed, 2)
        offset = back * offset + velocity * dt
        angle = a_roll * angle + np.sqrt(1 - a_roll**2) * rng.normal(0.0, roll_sd)
        path[k] = (offset[0], offset[1], angle)
    return path


def apply_ego_motion(rows: np.ndarray, path: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """MOT rows (gt or detections) seen by the moving camera: each box centre rotated about the
    image centre by its frame's angle and shifted by its offset (sizes kept: small boxes, small
    angles); rows whose centre leaves the image are dropped."""
    rows = np.asarray(rows, dtype=np.float64).copy()
    if not len(rows):
        return rows.reshape(0, 10)
    step = path[rows[:, 0].astype(int) - 1]
    middle = np.array([size[0] / 2.0, size[1] / 2.0])
    centre = rows[:, 2:4] + rows[:, 4:6] / 2 - middle
    cos, sin = np.cos(step[:, 2]), np.sin(step[:, 2])
    moved = np.column_stack([cos * centre[:, 0] - sin * centre[:, 1], sin * centre[:, 0] + cos * centre[:, 1]])
    moved += middle + step[:, :2]
    rows[:, 2:4] = moved - rows[:, 4:6] / 2
    keep = (moved[:, 0] >= 0) & (moved[:, 0] < size[0]) & (moved[:, 1] >= 0) & (moved[:, 1] < size[1])
    return rows[keep]


# --------------------------------------------------------------------------------- profiles
@dataclass(frozen=True)
class StreamSequence:
    """One benchmark sequence: ground truth, the detection stream trackers see, and its clock."""

    name: str
    gt: np.ndarray
    dets: np.ndarray
    fps: float
    size: tuple[int, int]
    frames: int


TUNING = "tuning"
HELD_OUT = "held-out"


@dataclass(frozen=True)
class StreamProfile:
    """A family of benchmark streams: ground truth generator, frame rate, failure model, camera.

    ``params`` are stated at :data:`REFERENCE_FPS` and rescaled to ``fps``
    (:meth:`StreamParams.at_fps`). ``role`` is :data:`TUNING` (tracker defaults may be tuned on
    it) or :data:`HELD_OUT` (never tuned on: it checks that tuning generalises).
    """

    name: str
    role: str
    description: str
    generator: str = "crossing"  # "crossing" (crossing_multi_target_gt) or "scene" (gldt_core.sim)
    fps: float = 30.0
    size: tuple[int, int] = (1920, 1080)
    targets: tuple[int, int] = (2, 5)
    params: StreamParams = StreamParams()
    ego_motion: EgoMotion | None = None

    def summary(self) -> dict:
        """Every parameter, for reports."""
        return dataclasses.asdict(self)


#: The synthetic profiles of ``gldt bench tracking`` (the real-detector streams are a further
#: held-out profile, :mod:`gldt_core.eval.detector_streams`).
PROFILES: tuple[StreamProfile, ...] = (
    StreamProfile(
        name="ours",
        role=TUNING,
        description="our own stream model on gldt_core.sim scenes (3 drones + birds): what the defaults were tuned on",
        generator="scene",
        targets=(3, 3),
    ),
    StreamProfile(
        name="crossing",
        role=TUNING,
        description="2-5 targets that cross and occlude each other; our stream model with more low scores",
        params=StreamParams(low_score_rate=0.35, low_score=(0.1, 0.5)),
    ),
    StreamProfile(
        name="occlusion-15hz",
        role=HELD_OUT,
        description="15 Hz, 1280x720; long occlusion bursts (1-4 s), wide Beta(2,3) scores, strong jitter, clutter",
        fps=15.0,
        size=(1280, 720),
        params=StreamParams(
            burst_rate=0.008,
            burst_frames=(30, 120),
            miss_rate=0.08,
            min_visibility=0.5,
            score_beta=(2.0, 3.0),
            jitter_frac=0.12,
            size_jitter_frac=0.12,
            fp_rate=0.5,
            fp_score=(0.1, 0.6),
        ),
    ),
    StreamProfile(
        name="drifting-clutter-60hz",
        role=HELD_OUT,
        description="60 Hz; false objects that persist 2-10 s and move like targets; Beta(5,2) scores",
        fps=60.0,
        params=StreamParams(
            score_beta=(5.0, 2.0),
            jitter_frac=0.06,
            fp_rate=0.2,
            clutter_tracks_rate=0.01,
            clutter_tracks_frames=(60, 300),
            clutter_tracks_speed=(1.5, 8.0),
            clutter_tracks_detect=0.85,
            clutter_tracks_score=(0.3, 0.85),
        ),
    ),
    StreamProfile(
        name="ego-motion-25hz",
        role=HELD_OUT,
        description="25 Hz; camera pan/roll walk moving every box; near-uniform Beta(1.2,1.2) scores; drifting clutter",
        fps=25.0,
        params=StreamParams(score_beta=(1.2, 1.2), jitter_frac=0.1, clutter_tracks_rate=0.004),
        ego_motion=EgoMotion(),
    ),
)


def profile_by_name(name: str) -> StreamProfile:
    """The profile of :data:`PROFILES` called ``name``; ValueError listing the names otherwise."""
    for profile in PROFILES:
        if profile.name == name:
            return profile
    raise ValueError(f"unknown stream profile {name!r} (known: {', '.join(p.name for p in PROFILES)})")


def _scene_generator() -> Callable[..., np.ndarray]:
    try:
        from gldt_core.sim import scene_ground_truth

        return scene_ground_truth
    except ImportError:  # the sim package is optional for this module: fall back to the plain generator
        return simple_multi_target_gt


def profile_sequences(profile: StreamProfile, seed: int, count: int, seconds: float) -> list[StreamSequence]:
    """``count`` sequences of ``seconds`` each (``round(seconds * fps)`` frames) of ``profile``,
    deterministic for ``(profile.name, seed)``: gt, then detections, then ego-motion on both."""
    if count < 0 or not seconds > 0:
        raise ValueError(f"count must be >= 0 and seconds > 0, got {count}, {seconds}")
    generator = _scene_generator() if profile.generator == "scene" else crossing_multi_target_gt
    params = profile.params.at_fps(profile.fps)
    frames = max(2, round(seconds * profile.fps))
    tag = zlib.crc32(profile.name.encode("utf-8"))
    out = []
    for k in range(count):
        rng = np.random.default_rng([seed, tag, k])
        targets = int(rng.integers(profile.targets[0], profile.targets[1] + 1))
        gt_seed, det_seed, ego_seed = (int(s) for s in rng.integers(0, 2**31 - 1, 3))
        gt = generator(gt_seed, frames, size=profile.size, targets=targets, fps=profile.fps)
        dets = detections_from_gt(gt, det_seed, profile.size, params, num_frames=frames)
        if profile.ego_motion is not None:
            path = ego_motion_path(ego_seed, frames, profile.fps, profile.ego_motion)
            gt = apply_ego_motion(gt, path, profile.size)
            dets = apply_ego_motion(dets, path, profile.size)
        out.append(StreamSequence(f"{profile.name}-{k:02d}", gt, dets, profile.fps, profile.size, frames))
    return out
