"""A synthetic scene as a frame source (``synth:seed=3,frames=90,targets=2,size=1920x1080``)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from gldt_core.io.frame import Frame, FrameSource
from gldt_core.sim.spec import SceneSpec, parse_size


class SynthSource(FrameSource):
    """Frames of a :class:`gldt_core.sim.SceneRenderer`, with exact ground truth."""

    def __init__(self, spec: SceneSpec) -> None:
        from gldt_core.sim.render import SceneRenderer

        self.renderer = SceneRenderer(spec)
        self.fps = self.renderer.fps
        self.size = self.renderer.size
        self.camera_matrix = self.renderer.camera_matrix()
        self.name = spec.name or f"synth-{spec.seed:06d}"

    def __len__(self) -> int:
        return len(self.renderer)

    @property
    def ground_truth(self) -> np.ndarray:
        return self.renderer.ground_truth()

    def __iter__(self) -> Iterator[Frame]:
        for index in range(len(self.renderer)):
            image, rows = self.renderer.render_with_truth(index)
            yield Frame(index, index / self.fps, image, rows)


def parse_synth_uri(text: str) -> SceneSpec:
    """``synth:seed=3,frames=90[,targets=2][,size=WxH][,fps=30]`` -> SceneSpec."""
    body = text.split(":", 1)[1] if ":" in text else ""
    fields: dict[str, Any] = {}  # SceneSpec field -> value parsed for that field; SceneSpec validates
    for item in filter(None, body.split(",")):
        key, _, value = item.partition("=")
        key = key.strip()
        if key in ("seed", "frames", "targets", "birds"):
            fields[key] = int(value)
        elif key == "size":
            fields[key] = parse_size(value)
        elif key == "fps":
            fields[key] = float(value)
        else:
            raise ValueError(f"{text!r}: unknown synth field {key!r} (seed, frames, targets, birds, size, fps)")
    if "seed" not in fields or "frames" not in fields:
        raise ValueError(f"{text!r}: synth sources need seed= and frames=")
    return SceneSpec(**fields)
