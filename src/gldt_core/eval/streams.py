"""Detection streams made from ground truth, with the failure modes a real detector has.

Used by ``gldt bench tracking`` to compare trackers "at equal detections": every tracker sees the
same stream. A stream is deterministic for a seed and models

* **misses in bursts** (occlusion by clouds, a drone behind a tree line, detector blind spots):
  per object a two-state Markov chain enters a miss burst with probability ``burst_rate`` per
  frame and stays in it for a uniformly drawn ``burst_frames`` length; ground-truth visibility
  below ``min_visibility`` is always a miss; plus independent misses at ``miss_rate``;
* **low-confidence detections**: a fraction ``low_score_rate`` of true detections get a score in
  ``low_score`` (the band ByteTrack's second stage exists for), the rest in ``high_score``;
* **box jitter**: centre noise with standard deviation ``jitter_frac`` of the box size (plus
  ``jitter_px``), size noise ``size_jitter_frac``;
* **false positives**: Poisson(``fp_rate``) clutter boxes per frame of target-like size anywhere
  in the image, and distractors (birds, class 2-4 in the gt) detected with ``distractor_rate``.

Output rows are MOTChallenge det lines ``frame, -1, x, y, w, h, score, -1, -1, -1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StreamParams:
    """Detector failure model; defaults give a hard but realistic small-drone stream."""

    burst_rate: float = 0.015
    burst_frames: tuple[int, int] = (8, 60)
    miss_rate: float = 0.05
    min_visibility: float = 0.25
    low_score_rate: float = 0.2
    low_score: tuple[float, float] = (0.15, 0.5)
    high_score: tuple[float, float] = (0.55, 0.95)
    jitter_frac: float = 0.08
    jitter_px: float = 0.5
    size_jitter_frac: float = 0.08
    fp_rate: float = 0.3
    fp_score: tuple[float, float] = (0.2, 0.7)
    distractor_rate: float = 0.5
    target_classes: tuple[int, ...] = (1,)


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
    for f in range(1, num_frames + 1):
        block = gt[starts[f - 1] : starts[f]]
        target = is_target[starts[f - 1] : starts[f]]
        for row, tgt in zip(block, target):
            key = (int(row[1]), int(tgt))
            if not tgt:
                if rng.random() < p.distractor_rate:
                    rows.append(_jittered(row, f, rng.uniform(*p.fp_score), p, rng))
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
            band = p.low_score if rng.random() < p.low_score_rate else p.high_score
            rows.append(_jittered(row, f, rng.uniform(*band), p, rng))
        for _ in range(rng.poisson(p.fp_rate)):
            w, h = typical * rng.uniform(0.6, 1.6, 2)
            x, y = rng.uniform(0, width - w), rng.uniform(0, height - h)
            rows.append(np.array([f, -1, x, y, w, h, rng.uniform(*p.fp_score), -1, -1, -1]))
    if not rows:
        return np.zeros((0, 10))
    return np.vstack(rows)


def _jittered(row: np.ndarray, frame: int, score: float, p: StreamParams, rng: np.random.Generator) -> np.ndarray:
    w, h = row[4], row[5]
    size = 0.5 * (w + h)
    cx = row[2] + w / 2 + rng.normal(0, p.jitter_frac * size + p.jitter_px)
    cy = row[3] + h / 2 + rng.normal(0, p.jitter_frac * size + p.jitter_px)
    w2 = max(1.0, w * (1 + rng.normal(0, p.size_jitter_frac)))
    h2 = max(1.0, h * (1 + rng.normal(0, p.size_jitter_frac)))
    return np.array([frame, -1, cx - w2 / 2, cy - h2 / 2, w2, h2, score, -1, -1, -1])


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
