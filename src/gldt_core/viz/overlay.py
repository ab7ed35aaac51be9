"""Draw what the GL-DT system did on a frame: track boxes with ids, the mode, and the LD windows."""

from __future__ import annotations

import numpy as np

_ROI_COLOUR = (255, 200, 0)  # BGR: cyan-ish, distinct from track colours
_TEXT_COLOUR = (255, 255, 255)


def colour_for_id(track_id: int) -> tuple[int, int, int]:
    """A stable, well-separated BGR colour per id (golden-ratio hue walk)."""
    import colorsys

    hue = (int(track_id) * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(hue, 0.85, 1.0)
    return int(b * 255), int(g * 255), int(r * 255)


def draw_overlay(
    frame: np.ndarray,
    tracks: np.ndarray,
    mode: str,
    rois: np.ndarray | None = None,
    frame_index: int | None = None,
) -> np.ndarray:
    """Return a copy of ``frame`` with ``tracks`` ``(M, >=5)`` ``[x1,y1,x2,y2,id,...]``, the mode
    label (``GD``/``LD``) and the ROIs drawn; line widths scale with the frame so 640x512 and
    1080p both stay readable."""
    import cv2

    out = frame.copy()
    height, width = out.shape[:2]
    scale = max(0.4, min(width, height) / 1080.0)
    thickness = max(1, int(round(2 * scale)))
    font = cv2.FONT_HERSHEY_SIMPLEX
    if rois is not None:
        for x1, y1, x2, y2 in np.asarray(rois, dtype=np.int64).reshape(-1, 4):
            cv2.rectangle(out, (int(x1), int(y1)), (int(x2) - 1, int(y2) - 1), _ROI_COLOUR, thickness)
    rows = np.asarray(tracks, dtype=np.float64)
    rows = rows.reshape(0, 6) if rows.size == 0 else np.atleast_2d(rows)
    for row in rows:
        x1, y1, x2, y2, track_id = (int(round(v)) for v in row[:5])
        colour = colour_for_id(track_id)
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, thickness)
        cv2.putText(out, str(track_id), (x1, max(0, y1 - 4)), font, 0.6 * scale + 0.2, colour, thickness)
    label = f"{mode}" if frame_index is None else f"{mode}  frame {frame_index}"
    if rois is not None and len(rois):
        label += f"  {len(rois)} ROI"
    cv2.putText(out, label, (10, int(30 * scale) + 10), font, 1.0 * scale, _TEXT_COLOUR, thickness + 1)
    return out
