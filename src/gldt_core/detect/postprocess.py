"""Pre- and post-processing around the ONNX detectors, in numpy/OpenCV only (no torch).

The exported models output ``(B, 4 + nc, A)``: xyxy boxes normalised to the input size and
per-class sigmoid scores. Everything needed to turn that into full-frame detections lives here so
that training validation (:mod:`gldt_core.training.train`), the runtime detectors
(:mod:`gldt_core.detect.global_detector`, :mod:`gldt_core.detect.local_detector`) and the
benchmarks all decode the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

PAD_VALUE = 114  # grey letterbox border, as in YOLO training
MAX_CANDIDATES = 1000  # highest-scoring anchors that enter NMS


@dataclass(frozen=True)
class Letterbox:
    """How a frame was resized and padded into the network input (to map boxes back)."""

    scale: float
    pad_x: int
    pad_y: int
    input_w: int
    input_h: int


def rect_input_size(frame_w: int, frame_h: int, long_side: int, multiple: int) -> tuple[int, int]:
    """Smallest ``(w, h)`` that holds the frame scaled so its long side is ``long_side``, both sides
    multiples of ``multiple``."""
    if frame_w <= 0 or frame_h <= 0:
        raise ValueError(f"frame size must be positive, got {frame_w}x{frame_h}")
    scale = long_side / max(frame_w, frame_h)
    w = int(np.ceil(round(frame_w * scale, 6) / multiple) * multiple)
    h = int(np.ceil(round(frame_h * scale, 6) / multiple) * multiple)
    return max(w, multiple), max(h, multiple)


def letterbox(
    image: np.ndarray, input_w: int, input_h: int, max_scale: float | None = None
) -> tuple[np.ndarray, Letterbox]:
    """Resize keeping aspect ratio and pad (centred) to ``input_w x input_h``; returns image and mapping.

    ``max_scale`` caps the resize factor: an image smaller than the input is then padded rather
    than enlarged beyond it (the local detector's objects keep the size it learned them at)."""
    h, w = image.shape[:2]
    scale = min(input_w / w, input_h / h)
    if max_scale is not None:
        scale = min(scale, max_scale)
    new_w, new_h = max(int(round(w * scale)), 1), max(int(round(h * scale)), 1)
    if (new_w, new_h) != (w, h):
        # Area averaging only for strong reductions (a 1080p frame to 640 wide, where it avoids
        # aliasing and has an integer-ratio fast path). For mild ones, such as a 300 px ROI to the
        # local model's 256, INTER_AREA costs an order of magnitude more than bilinear per crop,
        # and bilinear is what training saw (cv2.warpAffine has no area mode and falls back to it).
        interp = cv2.INTER_AREA if scale < 0.5 else cv2.INTER_LINEAR
        image = cv2.resize(image, (new_w, new_h), interpolation=interp)
    pad_x, pad_y = (input_w - new_w) // 2, (input_h - new_h) // 2
    out = np.full((input_h, input_w, 3), PAD_VALUE, dtype=np.uint8)
    out[pad_y : pad_y + new_h, pad_x : pad_x + new_w] = image
    return out, Letterbox(scale, pad_x, pad_y, input_w, input_h)


def to_blob(images_bgr: list[np.ndarray]) -> np.ndarray:
    """BGR uint8 HxWx3 images (same size) -> ``(B, 3, H, W)`` float32 RGB in [0, 1], the model input."""
    batch = np.stack(images_bgr)[..., ::-1]
    return np.ascontiguousarray(batch.transpose(0, 3, 1, 2), dtype=np.float32) / np.float32(255.0)


def ensure_bgr(frame: np.ndarray, name: str = "frame") -> np.ndarray:
    """Accept HxWx3 BGR, HxW or HxWx1 grayscale (converted), or HxWx4 BGRA (alpha dropped); reject the rest."""
    if not isinstance(frame, np.ndarray):
        raise ValueError(f"{name} must be a numpy array, got {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8 (0-255 BGR), got dtype {frame.dtype}")
    if frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 1):
        frame = cv2.cvtColor(frame.reshape(frame.shape[0], frame.shape[1]), cv2.COLOR_GRAY2BGR)
    elif frame.ndim == 3 and frame.shape[2] == 4:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
    elif not (frame.ndim == 3 and frame.shape[2] == 3):
        raise ValueError(f"{name} must be HxWx3 BGR (or grayscale HxW), got shape {frame.shape}")
    if frame.shape[0] < 8 or frame.shape[1] < 8:
        raise ValueError(f"{name} is too small ({frame.shape[1]}x{frame.shape[0]}); need at least 8x8 pixels")
    return frame


def nms(
    boxes: np.ndarray, scores: np.ndarray, iou_threshold: float, nested_threshold: float | None = None
) -> np.ndarray:
    """Greedy non-maximum suppression; returns kept indices sorted by descending score.

    With ``nested_threshold``, a box is also suppressed when more than that share of the smaller
    of it and a kept box lies inside the other (one box nested in another: a part of the object,
    or the object with its surroundings), whatever their IoU."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.int64)
    x1, y1, x2, y2 = boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3]
    areas = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    while order.size:
        i = order[0]
        keep.append(int(i))
        rest = order[1:]
        w = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        h = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = w * h
        iou = inter / np.maximum(areas[i] + areas[rest] - inter, 1e-9)
        keep_rest = iou <= iou_threshold
        if nested_threshold is not None:
            keep_rest &= inter / np.maximum(np.minimum(areas[i], areas[rest]), 1e-9) <= nested_threshold
        order = rest[keep_rest]
    return np.asarray(keep, dtype=np.int64)


def decode_output(
    output: np.ndarray,
    score_threshold: float,
    iou_threshold: float = 0.5,
    max_detections: int = 300,
    class_agnostic: bool = True,
    box_scale: tuple[float, float] = (1.0, 1.0),
    channels: np.ndarray | None = None,
) -> np.ndarray:
    """One image's ``(4 + nc, A)`` model output -> ``(N, 6)`` ``[x1, y1, x2, y2, score, class_index]``.

    The exported models give boxes normalised to the input size; ``box_scale = (input_w, input_h)``
    turns them into input pixels. Each anchor keeps its best class; NMS is class-agnostic by
    default because a box is either a drone or a bird, never both, and the tracker wants one box
    per object.

    ``channels`` (class indices) restricts the question to those classes: each anchor keeps its
    best class *among them*, scored by that class's own score. Why: a caller that tracks drones
    asks "is there a drone here?", and the answer is the drone score, whether or not a bird score
    is higher at the same anchor. Asked over every class, a model labels some drones birds and
    they are lost to the tracker (``gldt bench detection`` counts them under "where the drones
    went"; see docs/experiment-log.md).
    """
    if output.ndim != 2 or output.shape[0] < 5:
        raise ValueError(f"model output must be (4 + nc, A), got shape {output.shape}")
    scores_all = output[4:]
    if channels is not None:
        channels = np.asarray(channels, dtype=np.int64)
        if channels.ndim != 1 or len(channels) == 0 or channels.min() < 0 or channels.max() >= len(scores_all):
            raise ValueError(
                f"channels must be a non-empty list of class indices below {len(scores_all)}, got {channels.tolist()}"
            )
        scores_all = scores_all[channels]
    cls = scores_all.argmax(0)
    score = scores_all[cls, np.arange(scores_all.shape[1])]
    keep = score >= score_threshold
    if not keep.any():
        return np.zeros((0, 6), dtype=np.float32)
    if keep.sum() > MAX_CANDIDATES:  # bound NMS cost at very low thresholds
        kept = np.flatnonzero(keep)
        top = kept[np.argpartition(-score[kept], MAX_CANDIDATES - 1)[:MAX_CANDIDATES]]
        keep = np.zeros_like(keep)
        keep[top] = True
    boxes = output[:4, keep].T.astype(np.float32) * np.asarray(box_scale * 2, dtype=np.float32)
    score, cls = score[keep].astype(np.float32), cls[keep]
    if channels is not None:
        cls = channels[cls]
    finite = np.isfinite(boxes).all(1) & np.isfinite(score)
    if not finite.all():  # a NaN box gives NaN IoUs, which NMS reads as overlap and suppresses valid boxes
        boxes, score, cls = boxes[finite], score[finite], cls[finite]
    if class_agnostic:
        idx = nms(boxes, score, iou_threshold)
    else:
        offset = (cls.astype(np.float32) * 1e5)[:, None]
        idx = nms(boxes + offset, score, iou_threshold)
    idx = idx[:max_detections]
    return np.concatenate((boxes[idx], score[idx, None], cls[idx, None].astype(np.float32)), 1)


def unletterbox(dets: np.ndarray, lb: Letterbox, frame_w: int, frame_h: int) -> np.ndarray:
    """Map ``(N, >=4)`` xyxy boxes from network input pixels back to frame pixels (clipped to the frame)."""
    out = dets.copy()
    out[:, [0, 2]] = (out[:, [0, 2]] - lb.pad_x) / lb.scale
    out[:, [1, 3]] = (out[:, [1, 3]] - lb.pad_y) / lb.scale
    out[:, [0, 2]] = out[:, [0, 2]].clip(0, frame_w)
    out[:, [1, 3]] = out[:, [1, 3]].clip(0, frame_h)
    return out


def drop_degenerate(detections: np.ndarray) -> np.ndarray:
    """Remove boxes that clipping to the frame reduced to zero width or height."""
    return detections[(detections[:, 2] > detections[:, 0]) & (detections[:, 3] > detections[:, 1])]


def tile_rois(frame_w: int, frame_h: int, side: int = 300, min_overlap: int = 40) -> np.ndarray:
    """``(R, 4)`` int ROIs of ``side x side`` covering the frame with at least ``min_overlap`` px overlap."""

    def starts(length: int) -> list[int]:
        if length <= side:
            return [0]
        n = int(np.ceil((length - min_overlap) / (side - min_overlap)))
        return [int(round(i * (length - side) / (n - 1))) for i in range(n)]

    rois = [[x, y, x + side, y + side] for y in starts(frame_h) for x in starts(frame_w)]
    return np.asarray(rois, dtype=np.int64)
