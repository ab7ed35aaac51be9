"""Contact sheets: a grid of frames with their ground-truth boxes and zoomed target crops.

Targets are a few pixels wide in a 1080p frame, invisible in a thumbnail, so each tile also shows
every box's neighbourhood enlarged along its bottom edge: that is where a human checks that the
drawn drone and its box agree.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from gldt_core.sim.render import SceneRenderer

TILE_W = 640
CROP = 72  # zoomed crop side in the tile
DRONE_COLOUR = (60, 220, 60)
BIRD_COLOUR = (0, 200, 255)


def annotate_tile(image: np.ndarray, rows: np.ndarray, label: str = "") -> np.ndarray:
    """One contact-sheet tile: the frame scaled to ``TILE_W`` wide, boxes, and zoomed crops."""
    height, width = image.shape[:2]
    scale = TILE_W / width
    tile_h = int(round(height * scale))
    tile = cv2.resize(image, (TILE_W, tile_h), interpolation=cv2.INTER_AREA)
    crops = []
    for row in rows:
        x, y, w, h = row[2:6]
        colour = DRONE_COLOUR if int(row[7]) == 1 else BIRD_COLOUR
        p1 = (int(x * scale) - 2, int(y * scale) - 2)
        p2 = (int((x + w) * scale) + 2, int((y + h) * scale) + 2)
        cv2.rectangle(tile, p1, p2, colour, 1)
        cv2.putText(
            tile,
            f"{int(row[1])} v{row[8]:.2f}",
            (p1[0], max(p1[1] - 3, 8)),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.3,
            colour,
            1,
            cv2.LINE_AA,
        )
        side = int(max(w, h) * 1.6) + 8
        cx, cy = x + w / 2, y + h / 2
        x0, y0 = int(cx - side / 2), int(cy - side / 2)
        padded = cv2.copyMakeBorder(image, side, side, side, side, cv2.BORDER_CONSTANT)
        crop = padded[y0 + side : y0 + 2 * side, x0 + side : x0 + 2 * side].copy()
        zoom = CROP / side
        crop = cv2.resize(crop, (CROP, CROP), interpolation=cv2.INTER_NEAREST)
        bx0 = int((x - x0) * zoom)
        by0 = int((y - y0) * zoom)
        cv2.rectangle(crop, (bx0, by0), (int(bx0 + w * zoom), int(by0 + h * zoom)), colour, 1)
        crops.append(crop)
    strip = np.zeros((CROP, TILE_W, 3), np.uint8)
    for index, crop in enumerate(crops[: TILE_W // CROP]):
        strip[:, index * CROP : (index + 1) * CROP] = crop
    if label:
        cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 2, cv2.LINE_AA)
        cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([tile, strip])


def contact_sheet(tiles: Sequence[np.ndarray], columns: int = 3) -> np.ndarray:
    """Arrange equally sized tiles in a grid (missing cells black)."""
    if not tiles:
        raise ValueError("contact sheet needs at least one tile")
    tile_h, tile_w = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    sheet = np.zeros((rows * tile_h, columns * tile_w, 3), np.uint8)
    for index, tile in enumerate(tiles):
        r, c = divmod(index, columns)
        sheet[r * tile_h : (r + 1) * tile_h, c * tile_w : (c + 1) * tile_w] = tile
    return sheet


def scene_preview(renderer: SceneRenderer, count: int = 9, columns: int = 3) -> np.ndarray:
    """A contact sheet of ``count`` frames spread over the scene of ``renderer``."""
    frames = len(renderer)
    picks = sorted(set(np.linspace(0, frames - 1, min(count, frames)).round().astype(int).tolist()))
    tiles = []
    for frame in picks:
        image, rows = renderer.render_with_truth(frame)
        tiles.append(annotate_tile(image, rows, f"seed {renderer.spec.seed} frame {frame + 1}"))
    return contact_sheet(tiles, columns)
