"""Copy-paste augmentation: labelled objects cut from one training clip and matted into another.

Why: each Halmstad clip holds one kind of object against one kind of background (drones over tree
lines, birds against cloud, ...). A small detector trained on whole clips learns the *scene* as a
class cue, so on a held-out clip it calls a drone a bird (asked about every class, the shipped
AM-YOLO boxes some held-out drones in the right place and size, with the wrong class). Pasting
drones into bird and airplane clips, and birds and airplanes into drone clips, is meant to take
that shortcut away, and adds object-background combinations the 59 training drone clips never
show. The experiments (``docs/experiment-log.md``) found that it cuts false drones on bird clips
but costs drone recall at this model size, so the shipped configs leave it off.

Objects are matted, not pasted as rectangles: a rectangle of foreign sky around a pasted drone
would be a cue that never occurs at run time. The matte is the pixel's difference from the
colour of the ring of background around the box, softened at its edge (see :func:`soft_matte`).

For the dual-frame model the object is cut at the same place from the source's previous and
current frames and pasted at the same place in both target frames, so it keeps the source's own
frame-to-frame motion against a background that keeps the target's.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Pixels of background kept around an object's box when it is cut (for the matte's ring).
MARGIN = 4
#: Objects whose box is smaller than this (frame px) are not cut: too few pixels to matte.
MIN_SIDE = 4.0
#: An object whose matte covers less than this share of its box is not cut: it barely stands out
#: from its own background (a faint airplane in haze), and pasted it would teach the detector to
#: find objects in empty sky.
MIN_MATTE_COVER = 0.08


@dataclass(frozen=True)
class ObjectPatch:
    """One object: its class index and the padded patches from the previous and current frames."""

    class_index: int
    previous: np.ndarray  # (h, w, 3) uint8, the box plus MARGIN on every side
    current: np.ndarray
    previous_matte: np.ndarray  # (h, w) float32 in [0, 1]
    current_matte: np.ndarray
    box: tuple[float, float, float, float]  # the object's box x1, y1, x2, y2 in patch pixels


def soft_matte(patch: np.ndarray, margin: int = MARGIN) -> np.ndarray:
    """Alpha of the object in a padded patch: how far each pixel is from the ring's background.

    The ring (the ``margin`` pixels around the box) gives the local background's median colour and
    its spread; a pixel inside the box is opaque where it differs from that colour by several
    spreads, transparent where it matches, and the whole matte is blurred by one pixel so the
    pasted edge has no hard step. Outside the box the matte is zero.
    """
    h, w = patch.shape[:2]
    image = patch.astype(np.float32)
    ring = np.ones((h, w), bool)
    ring[margin : h - margin, margin : w - margin] = False
    background = np.median(image[ring], axis=0)
    spread = np.median(np.abs(image[ring] - background), axis=0).max() + 4.0
    distance = np.abs(image - background).max(axis=2)
    alpha = np.clip((distance - 1.5 * spread) / (2.0 * spread), 0.0, 1.0)
    alpha[ring] = 0.0
    return cv2.GaussianBlur(alpha, (3, 3), 0.8)


def cut_objects(previous: np.ndarray, current: np.ndarray, boxes: np.ndarray) -> list[ObjectPatch]:
    """Patches of every box (rows ``class, x1, y1, x2, y2`` in frame px) that fits in the frame."""
    h, w = current.shape[:2]
    out: list[ObjectPatch] = []
    for cls, x1, y1, x2, y2 in np.asarray(boxes, np.float64).reshape(-1, 5):
        if x2 - x1 < MIN_SIDE or y2 - y1 < MIN_SIDE:
            continue
        a, b = int(np.floor(x1)) - MARGIN, int(np.floor(y1)) - MARGIN
        c, d = int(np.ceil(x2)) + MARGIN, int(np.ceil(y2)) + MARGIN
        if a < 0 or b < 0 or c > w or d > h:
            continue
        prev, cur = previous[b:d, a:c].copy(), current[b:d, a:c].copy()
        current_matte = soft_matte(cur)
        if current_matte.sum() < MIN_MATTE_COVER * (x2 - x1) * (y2 - y1):
            continue
        box = (float(x1 - a), float(y1 - b), float(x2 - a), float(y2 - b))
        out.append(ObjectPatch(int(cls), prev, cur, soft_matte(prev), current_matte, box))
    return out


class ObjectBank:
    """Object patches by class, cut once from the training pairs (a bounded, seeded sample)."""

    def __init__(self, patches: list[ObjectPatch]):
        if not patches:
            raise ValueError(
                "copy-paste needs at least one object patch; the training pairs have no box of at least 4 px"
            )
        self.by_class: dict[int, list[ObjectPatch]] = {}
        for patch in patches:
            self.by_class.setdefault(patch.class_index, []).append(patch)
        self.classes = sorted(self.by_class)

    def __len__(self) -> int:
        return sum(len(v) for v in self.by_class.values())

    @classmethod
    def from_pairs(cls, pairs: list, per_class: int = 1500, seed: int = 0) -> ObjectBank:
        """Cut up to ``per_class`` objects of each class from ``pairs`` (:class:`~.data.FramePair`)."""
        rng = np.random.default_rng(seed)
        with_boxes = [i for i, p in enumerate(pairs) if len(p.boxes)]
        counts: dict[int, int] = {}
        patches: list[ObjectPatch] = []
        for i in rng.permutation(with_boxes):
            pair = pairs[int(i)]
            wanted = [row for row in pair.boxes if counts.get(int(row[0]), 0) < per_class]
            if not wanted:
                continue
            previous, current = pair.images()
            for patch in cut_objects(previous, current, np.asarray(wanted)):
                if counts.get(patch.class_index, 0) < per_class:
                    counts[patch.class_index] = counts.get(patch.class_index, 0) + 1
                    patches.append(patch)
        return cls(patches)

    def draw(self, rng: np.random.Generator) -> ObjectPatch:
        """A patch of a class chosen uniformly (so the rare classes are pasted as often as drones)."""
        group = self.by_class[self.classes[int(rng.integers(len(self.classes)))]]
        return group[int(rng.integers(len(group)))]


def _overlaps(box: np.ndarray, boxes: np.ndarray, pad: float) -> bool:
    if len(boxes) == 0:
        return False
    return bool(
        np.any(
            (box[0] - pad < boxes[:, 3])
            & (box[2] + pad > boxes[:, 1])
            & (box[1] - pad < boxes[:, 4])
            & (box[3] + pad > boxes[:, 2])
        )
    )


def paste_objects(
    images: list[np.ndarray],
    boxes: np.ndarray,
    bank: ObjectBank,
    rng: np.random.Generator,
    scale: float,
    count: int,
    tries: int = 10,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Paste ``count`` objects from ``bank`` into ``images`` (one frame, or previous and current).

    ``scale`` is the factor from frame pixels to these images' pixels (the crop's scale), so a
    pasted object has the size it would have had in the frame; a jitter of 0.8-1.25 on top varies
    it. Places overlapping an existing or already pasted box are skipped (after ``tries``).
    Returns new images and ``boxes`` (rows ``class, x1, y1, x2, y2``) with the pasted rows added.
    """
    out = [im.copy() for im in images]
    h, w = out[0].shape[:2]
    rows = [np.asarray(boxes, np.float32).reshape(-1, 5)]
    placed = rows[0]
    for _ in range(count):
        patch = bank.draw(rng)
        factor = scale * rng.uniform(0.8, 1.25)
        ph, pw = patch.current.shape[:2]
        size = (max(int(round(pw * factor)), 3), max(int(round(ph * factor)), 3))
        if size[0] >= w or size[1] >= h:
            continue
        sx, sy = size[0] / pw, size[1] / ph
        for _ in range(tries):
            x0, y0 = int(rng.integers(0, w - size[0] + 1)), int(rng.integers(0, h - size[1] + 1))
            bx1, by1, bx2, by2 = patch.box
            box = np.array([x0 + bx1 * sx, y0 + by1 * sy, x0 + bx2 * sx, y0 + by2 * sy], np.float32)
            if not _overlaps(box, placed, pad=2.0):
                break
        else:
            continue
        interpolation = cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR
        layers = (
            [(patch.current, patch.current_matte)]
            if len(out) == 1
            else [(patch.previous, patch.previous_matte), (patch.current, patch.current_matte)]
        )
        for image, (source, matte) in zip(out, layers):
            alpha = cv2.resize(matte, size, interpolation=cv2.INTER_LINEAR)[..., None]
            region = image[y0 : y0 + size[1], x0 : x0 + size[0]].astype(np.float32)
            pasted = cv2.resize(source, size, interpolation=interpolation).astype(np.float32)
            image[y0 : y0 + size[1], x0 : x0 + size[0]] = np.clip(
                alpha * pasted + (1 - alpha) * region + 0.5, 0, 255
            ).astype(np.uint8)
        row = np.array([[patch.class_index, *box]], np.float32)
        rows.append(row)
        placed = np.concatenate((placed, row))
    return out, np.concatenate(rows)
