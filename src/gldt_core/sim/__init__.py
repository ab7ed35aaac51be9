"""Synthetic air-to-air UAV scenes with exact ground truth (deterministic per seed).

Public API:

- :func:`scene_ground_truth` - the MOT ground truth of a scene, fast, without rendering.
- :func:`render_scene` - ``(frames, gt)``: a lazy list of frames (HxWx3 uint8 BGR) and the gt.
- :class:`SceneRenderer` - ``SceneRenderer(spec).render(k)`` renders frame ``k`` without
  rendering the frames before it; ``render_with_truth(k)`` also returns that frame's gt rows.
- :class:`SceneSpec` - one scene's parameters; :mod:`gldt_core.sim.presets` - train/val/test.

Ground truth class ids: 1 drone (ids 1..targets), 2 bird distractor (ids from 1001).
"""

from __future__ import annotations

from typing import Any

from gldt_core.sim.spec import BIRD_ID_BASE, CLASS_BIRD, CLASS_DRONE, SceneSpec

__all__ = [
    "BIRD_ID_BASE",
    "CLASS_BIRD",
    "CLASS_DRONE",
    "SceneRenderer",
    "SceneSpec",
    "presets",
    "render_scene",
    "scene_ground_truth",
]


def __getattr__(name: str) -> Any:
    """Import the heavier modules (cv2) only when their names are used."""
    if name == "scene_ground_truth":
        from gldt_core.sim.scene_geometry import scene_ground_truth

        return scene_ground_truth
    if name in ("SceneRenderer", "render_scene"):
        from gldt_core.sim import render

        return getattr(render, name)
    if name == "presets":
        import importlib

        return importlib.import_module("gldt_core.sim.presets")
    raise AttributeError(f"module 'gldt_core.sim' has no attribute {name!r}")
