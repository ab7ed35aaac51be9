"""Pixels of a synthetic scene: background crop, airframes drawn in small patches, sensor effects.

Per frame: crop the precomputed canvas at the camera offset (ego-motion), draw each object in a
supersampled patch around it (anti-aliased, motion blurred, faded by cloud occlusion and haze),
then apply exposure gain and sensor noise in one ``cv2.addWeighted`` pass with a shifted window of
a cached noise field, and optionally JPEG round-trip. Nothing depends on earlier frames, so any
frame can be rendered on its own and the same spec always gives the same bytes. Paths are kept for
one shot at a time (:mod:`gldt_core.sim.scene_geometry`), so a scene's length costs no memory.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import lru_cache
from typing import Unpack, overload

import cv2
import numpy as np

from gldt_core.sim.airframes import project
from gldt_core.sim.background import render_canvas
from gldt_core.sim.scene_geometry import ObjectState, SceneGeometry, rows_from_states
from gldt_core.sim.spec import SceneSpec, SpecExtras
from gldt_core.sim.style import STREAM_FRAME, STREAM_STYLE, camera_matrix

NOISE_PAD = 32
NOISE_SIGMA = 24.0
_SHIFT = 3  # fixed-point bits for sub-pixel drawing
ROTOR_GREY = np.array([120.0, 120.0, 122.0], np.float32)  # spinning rotor blur, any airframe


@lru_cache(maxsize=4)
def _noise_field(width: int, height: int) -> np.ndarray:
    """Gaussian noise (sigma 24 around 128) a little larger than the frame, shared by all scenes.

    Scenes scale it with their own sigma and pick a random window per frame, so per-frame noise
    costs no random draws over the whole image.
    """
    rng = np.random.default_rng(20240611)
    noise = rng.standard_normal(size=(height + NOISE_PAD, width + NOISE_PAD, 3), dtype=np.float32)
    noise *= NOISE_SIGMA
    noise += 128.5
    np.clip(noise, 0, 255, out=noise)
    return noise.astype(np.uint8)


class SceneRenderer:
    """Renders frames of one scene; ``render(k)`` is random access and deterministic."""

    def __init__(self, spec: SceneSpec) -> None:
        self.spec = spec
        self.geometry = SceneGeometry(spec)
        self.style = self.geometry.style
        self._canvas: np.ndarray | None = None
        phase_rng = spec.rng(STREAM_STYLE, 1)
        self._exposure_phase = float(phase_rng.uniform(0, 2 * np.pi))
        self._exposure_period = float(phase_rng.uniform(3.0, 9.0))

    # -- scene facts -----------------------------------------------------------------------
    @property
    def size(self) -> tuple[int, int]:
        return self.spec.size

    @property
    def fps(self) -> float:
        return self.spec.fps

    def __len__(self) -> int:
        return self.spec.frames

    def camera_matrix(self) -> np.ndarray:
        """Pinhole K (3x3) for this scene's field of view (used for ``camera_info``)."""
        return camera_matrix(self.spec.size, self.style.hfov_deg)

    def ground_truth(self, frame: int | None = None) -> np.ndarray:
        """MOT rows of one frame (0-based) or of the whole scene."""
        if frame is None:
            return self.geometry.all_ground_truth()
        return self.geometry.ground_truth(frame)

    @property
    def canvas(self) -> np.ndarray:
        if self._canvas is None:
            self._canvas = render_canvas(self.spec, self.style, self.geometry.clouds)
        return self._canvas

    # -- pixels ------------------------------------------------------------------------------
    def exposure_gain(self, frame: int) -> float:
        """Auto-exposure: a slow wobble plus a few smooth steps (sun, pan towards bright sky)."""
        t = frame / self.spec.fps
        gain = 1.0 + self.style.exposure_wobble * np.sin(2 * np.pi * t / self._exposure_period + self._exposure_phase)
        for when, change in self.style.exposure_steps:
            gain += change / (1.0 + np.exp(-(t - when) / 0.35))
        return float(gain)

    def render(self, frame: int, *, draw_objects: bool = True) -> np.ndarray:
        """Frame ``frame`` (0-based) as HxWx3 uint8 BGR; ``draw_objects=False`` gives the empty sky."""
        image, _ = self.render_with_truth(frame, draw_objects=draw_objects)
        return image

    def render_with_truth(self, frame: int, *, draw_objects: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``frame`` and its MOT rows (K, 10), from one pass over the scene geometry."""
        spec = self.spec
        states = self.geometry.objects(frame)
        shot, local = self.geometry.shot(frame)
        width, height = spec.size
        margin_x, margin_y = self.style.margin
        offset_x, offset_y = (int(v) for v in shot.camera[local])
        top, left = margin_y + offset_y, margin_x + offset_x
        image = self.canvas[top : top + height, left : left + width].copy()
        if draw_objects:
            for state in states:
                self._draw(image, state, shot.camera)
        rng = spec.rng(STREAM_FRAME, frame)
        dx, dy = (int(v) for v in rng.integers(0, NOISE_PAD, size=2))
        noise = _noise_field(width, height)[dy : dy + height, dx : dx + width]
        beta = self.style.noise_sigma / NOISE_SIGMA
        image = cv2.addWeighted(image, self.exposure_gain(frame), noise, beta, -128.0 * beta)
        if spec.jpeg_quality is not None:
            ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(spec.jpeg_quality)])
            if not ok:  # pragma: no cover - cv2 always encodes uint8 BGR
                raise RuntimeError("JPEG encoding failed")
            decoded = cv2.imdecode(encoded, cv2.IMREAD_COLOR)
            if decoded is None:  # pragma: no cover - cv2 always decodes what it just encoded
                raise RuntimeError("JPEG decoding failed")
            image = decoded
        return image, rows_from_states(states, frame, spec.size)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for frame in range(self.spec.frames):
            yield self.render_with_truth(frame)

    def sampled_pairs(
        self, frame_step: int, scale: float = 1.0
    ) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
        """``(t, previous, current, rows)`` for every ``frame_step``-th frame ``t`` from 1: the frame
        and the one before it, resized by ``scale`` (area interpolation), and the frame's MOT rows
        ``(K, 10)`` with their pixel columns (x, y, w, h) scaled alike. For training and crops."""
        width, height = self.spec.size
        size = (int(round(width * scale)), int(round(height * scale)))
        for t in range(1, self.spec.frames, frame_step):
            previous = self.render(t - 1)
            current, rows = self.render_with_truth(t)
            rows = np.asarray(rows, dtype=np.float64).reshape(-1, 10).copy()
            if scale != 1.0:
                previous = cv2.resize(previous, size, interpolation=cv2.INTER_AREA)
                current = cv2.resize(current, size, interpolation=cv2.INTER_AREA)
                rows[:, 2:6] *= scale
            yield t, previous, current, rows

    # -- drawing -------------------------------------------------------------------------------
    def _screen_velocity(self, state: ObjectState, camera: np.ndarray) -> np.ndarray:
        """Image motion of the object during the frame (px/frame), ego-motion included; ``camera``
        holds the offsets of the state's shot."""
        frame = state.frame
        track = state.track
        if len(camera) < 2:
            return np.zeros(2)
        a, b = (frame - 1, frame) if frame > 0 else (0, 1)
        return (track.centre[b] - camera[b]) - (track.centre[a] - camera[a])

    def _draw(self, image: np.ndarray, state: ObjectState, camera: np.ndarray) -> None:
        track = state.track
        span = float(track.span[state.frame])
        model = track.model(state.frame)
        velocity = self._screen_velocity(state, camera)
        blur = float(np.hypot(*velocity)) * self.style.blur_exposure
        pad = int(np.ceil(blur / 2)) + 2
        x0 = int(np.floor(state.box[0])) - pad
        y0 = int(np.floor(state.box[1])) - pad
        x1 = int(np.ceil(state.box[2])) + pad
        y1 = int(np.ceil(state.box[3])) + pad
        height, width = image.shape[:2]
        if x1 <= 0 or y1 <= 0 or x0 >= width or y0 >= height:
            return
        supersample = 4 if span < 32 else 2
        patch_w, patch_h = x1 - x0, y1 - y0
        alpha_ss = np.zeros((patch_h * supersample, patch_w * supersample), np.uint8)
        shade_ss = np.full_like(alpha_ss, 100)
        neutral_ss = np.zeros_like(alpha_ss)
        origin = np.array([x0, y0], float)
        for part in model.parts:
            offsets = project(part.points, state.rotation) * span
            points = (offsets + state.centre - origin) * supersample - 0.5
            fixed = np.rint(points * (1 << _SHIFT)).astype(np.int32)
            opacity = int(round(255 * part.alpha))
            shade = int(np.clip(100 * part.shade, 0, 255))
            neutral = 255 if part.neutral else 0
            if part.radius > 0:
                thickness = max(1, int(round(2 * part.radius * span * supersample)))
                for start, end in zip(fixed[:-1], fixed[1:]):
                    cv2.line(alpha_ss, tuple(start), tuple(end), opacity, thickness, cv2.LINE_8, _SHIFT)
                    cv2.line(shade_ss, tuple(start), tuple(end), shade, thickness, cv2.LINE_8, _SHIFT)
                    cv2.line(neutral_ss, tuple(start), tuple(end), neutral, thickness, cv2.LINE_8, _SHIFT)
            else:
                hull = cv2.convexHull(fixed)
                cv2.fillConvexPoly(alpha_ss, hull, opacity, cv2.LINE_8, _SHIFT)
                cv2.fillConvexPoly(shade_ss, hull, shade, cv2.LINE_8, _SHIFT)
                cv2.fillConvexPoly(neutral_ss, hull, neutral, cv2.LINE_8, _SHIFT)
        alpha: np.ndarray = (
            cv2.resize(alpha_ss, (patch_w, patch_h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
        )
        shade_map = cv2.resize(shade_ss, (patch_w, patch_h), interpolation=cv2.INTER_AREA).astype(np.float32) / 100.0
        grey = cv2.resize(neutral_ss, (patch_w, patch_h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
        colour = np.asarray(track.colour, np.float32)[None, None, :] * shade_map[..., None]
        colour = colour * (1 - grey[..., None]) + ROTOR_GREY * grey[..., None]
        # Aerial perspective: small (far) targets take on the colour of the air in front of them.
        cy = int(np.clip(state.centre[1], 0, height - 1))
        cx = int(np.clip(state.centre[0], 0, width - 1))
        haze = float(np.clip(0.3 - span / 120.0, 0.0, 0.3))
        colour = colour * (1 - haze) + image[cy, cx].astype(np.float32) * haze
        premultiplied = colour * alpha[..., None]
        if blur >= 1.0:
            kernel = _line_kernel(velocity, blur)
            alpha = cv2.filter2D(alpha, -1, kernel, borderType=cv2.BORDER_CONSTANT)
            premultiplied = cv2.filter2D(premultiplied, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        alpha *= 1.0 - state.occlusion
        premultiplied *= 1.0 - state.occlusion
        if track.behind_terrain:
            # Hidden below the skyline, pixel by pixel (same rule as the ground's coverage).
            margin_x, margin_y = self.style.margin
            offset_x, offset_y = camera[state.frame]
            ridge = self.geometry.ridge
            columns = np.clip(np.arange(x0, x1) + offset_x + margin_x, 0, len(ridge) - 1)
            rows = np.arange(y0, y1, dtype=np.float64) + offset_y + margin_y
            sky = np.clip(ridge[columns][None, :] - rows[:, None] + 0.5, 0.0, 1.0).astype(np.float32)
            alpha *= sky
            premultiplied *= sky[..., None]
        # Composite only the part of the patch inside the frame.
        ix0, iy0 = max(x0, 0), max(y0, 0)
        ix1, iy1 = min(x1, width), min(y1, height)
        sub = (slice(iy0 - y0, iy1 - y0), slice(ix0 - x0, ix1 - x0))
        region = image[iy0:iy1, ix0:ix1].astype(np.float32)
        a = alpha[sub][..., None]
        blended = region * (1 - a) + premultiplied[sub]
        image[iy0:iy1, ix0:ix1] = np.clip(blended + 0.5, 0, 255).astype(np.uint8)


def _line_kernel(velocity: np.ndarray, length: float) -> np.ndarray:
    """A normalised line kernel along ``velocity`` of ``length`` px (linear motion blur)."""
    size = int(np.ceil(length)) | 1
    size = max(size, 3)
    kernel: np.ndarray = np.zeros((size * 4, size * 4), np.float32)
    direction = velocity / max(float(np.hypot(*velocity)), 1e-6)
    centre = np.array([size * 2 - 0.5, size * 2 - 0.5])
    start = centre - direction * length * 2
    end = centre + direction * length * 2
    cv2.line(kernel, tuple(np.rint(start * 8).astype(int)), tuple(np.rint(end * 8).astype(int)), 1.0, 4, cv2.LINE_AA, 3)
    kernel = cv2.resize(kernel, (size, size), interpolation=cv2.INTER_AREA)
    return kernel / max(float(kernel.sum()), 1e-6)


class SceneFrames(Sequence[np.ndarray]):
    """The frames of a scene as a lazy sequence: ``frames[k]`` renders frame k on demand.

    Behaves like a list of HxWx3 uint8 BGR images (``len``, indexing, slicing, iteration) without
    holding a whole 1080p scene in memory; the last two frames are kept, so walking frame pairs
    ``(k - 1, k)`` renders each frame once.
    """

    def __init__(self, renderer: SceneRenderer) -> None:
        self.renderer = renderer
        self._recent: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self.renderer)

    def _frame(self, index: int) -> np.ndarray:
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range 0..{len(self) - 1}")
        image = self._recent.get(index)
        if image is None:
            image = self.renderer.render(index)
            self._recent = {k: v for k, v in self._recent.items() if abs(k - index) <= 1}
            self._recent[index] = image
        return image

    @overload
    def __getitem__(self, index: int) -> np.ndarray: ...

    @overload
    def __getitem__(self, index: slice) -> list[np.ndarray]: ...

    def __getitem__(self, index: int | slice) -> np.ndarray | list[np.ndarray]:
        if isinstance(index, slice):
            return [self._frame(k) for k in range(*index.indices(len(self)))]
        return self._frame(int(index))


def render_scene(
    seed: int,
    frames: int,
    size: tuple[int, int] = (1920, 1080),
    targets: int = 3,
    fps: float = 30.0,
    **spec_fields: Unpack[SpecExtras],
) -> tuple[SceneFrames, np.ndarray]:
    """``(frames, gt)``: the scene's frames (lazy list of BGR images) and its MOT ground truth.

    ``gt`` is exactly :func:`gldt_core.sim.scene_ground_truth` for the same arguments; extra
    keyword arguments are :class:`SceneSpec` fields (``target_size``, ``birds``, ``jpeg_quality``).
    """
    spec = SceneSpec(seed=seed, frames=frames, size=size, targets=targets, fps=fps, **spec_fields)
    renderer = SceneRenderer(spec)
    return SceneFrames(renderer), renderer.ground_truth()
