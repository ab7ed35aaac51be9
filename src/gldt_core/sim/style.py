"""Scene-wide random choices (sky, terrain, clouds, sun, camera, sensor) drawn once per seed.

Ground truth and renderer both read the same :class:`SceneStyle`, so the cloud cover that hides a
drone in the pixels is the one that lowers its visibility in the ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gldt_core.sim.spec import SceneSpec

STREAM_STYLE = 1
STREAM_CLOUDS = 2
STREAM_CAMERA = 3
STREAM_TARGET = 10  # + target index
STREAM_BIRD = 5000  # + bird index
STREAM_TEXTURE = 900
STREAM_RIDGE = 901
STREAM_FRAME = 1_000_000  # (STREAM_FRAME, frame index)

TERRAINS = ("none", "treeline", "terrain", "desert", "urban")

#: Sky palettes (zenith BGR, horizon BGR): clear blue, hazy, overcast, warm evening, pale.
SKY_PALETTES = (
    ((190, 135, 80), (235, 215, 195)),
    ((200, 160, 120), (225, 220, 215)),
    ((175, 172, 168), (205, 205, 200)),
    ((170, 140, 115), (170, 200, 230)),
    ((215, 185, 150), (240, 235, 228)),
)


@dataclass(frozen=True)
class SceneStyle:
    """Every scene-level choice; see the module docstring for why it is drawn in one place."""

    margin: tuple[int, int]  # ego-motion margin (x, y) px on each side of the view
    zenith: tuple[float, float, float]
    horizon_color: tuple[float, float, float]
    horizon_y: float  # horizon height in view px at zero camera offset (> height: no ground)
    terrain: str
    cloud_cover: float  # 0 clear .. 0.8 broken
    cloud_opacity: float
    sun_xy: tuple[float, float]  # in view px at zero offset; may be outside the view
    sun_strength: float
    noise_sigma: float  # sensor noise std in grey levels
    exposure_wobble: float
    exposure_steps: tuple[tuple[float, float], ...]  # (time s, relative gain change)
    blur_exposure: float  # shutter open fraction of the frame time (motion blur length)
    hfov_deg: float
    birds: int
    vignette: float


def _jittered(colour: tuple[float, float, float], jitter: np.ndarray) -> tuple[float, float, float]:
    """``colour`` plus per-channel ``jitter``, kept inside 0..255."""
    blue, green, red = (float(np.clip(c + j, 0, 255)) for c, j in zip(colour, jitter))
    return blue, green, red


def scene_style(spec: SceneSpec) -> SceneStyle:
    """Draw the scene-wide choices of ``spec`` from its style stream."""
    rng = spec.rng(STREAM_STYLE)
    width, height = spec.size
    palette = SKY_PALETTES[int(rng.integers(len(SKY_PALETTES)))]
    jitter = rng.normal(0.0, 8.0, size=6)
    zenith = _jittered(palette[0], jitter[:3])
    horizon = _jittered(palette[1], jitter[3:])
    ground_roll = rng.random()
    if ground_roll < 0.3:
        terrain = "none"
        horizon_y = float(height * rng.uniform(1.15, 1.6))
    else:
        terrain = TERRAINS[1 + int(rng.integers(len(TERRAINS) - 1))]
        horizon_y = float(height * rng.uniform(0.62, 0.95))
    cloud_cover = float(rng.choice([0.0, 0.1, 0.25, 0.4, 0.55, 0.7]))
    cloud_opacity = float(rng.uniform(0.7, 0.97))
    sun_xy = (float(width * rng.uniform(-0.3, 1.3)), float(height * rng.uniform(-0.4, 0.5)))
    sun_strength = float(rng.uniform(0.0, 1.0) ** 2)
    noise_sigma = float(rng.uniform(1.5, 6.0))
    exposure_wobble = float(rng.uniform(0.0, 0.06))
    n_steps = int(rng.integers(0, 3))
    exposure_steps = tuple((float(rng.uniform(0.5, 12.0)), float(rng.uniform(-0.18, 0.18))) for _ in range(n_steps))
    blur_exposure = float(rng.uniform(0.2, 0.8))
    hfov_deg = float(rng.uniform(35.0, 75.0))
    birds = int(rng.choice([0, 0, 1, 2, 3])) if spec.birds is None else int(spec.birds)
    vignette = float(rng.uniform(0.0, 0.25))
    margin = (max(8, int(round(0.1 * width))), max(8, int(round(0.1 * height))))
    return SceneStyle(
        margin=margin,
        zenith=zenith,
        horizon_color=horizon,
        horizon_y=horizon_y,
        terrain=terrain,
        cloud_cover=cloud_cover,
        cloud_opacity=cloud_opacity,
        sun_xy=sun_xy,
        sun_strength=sun_strength,
        noise_sigma=noise_sigma,
        exposure_wobble=exposure_wobble,
        exposure_steps=exposure_steps,
        blur_exposure=blur_exposure,
        hfov_deg=hfov_deg,
        birds=birds,
        vignette=vignette,
    )


def camera_matrix(size: tuple[int, int], hfov_deg: float) -> np.ndarray:
    """A pinhole ``K`` (3x3) for a camera of the given size and horizontal field of view."""
    width, height = size
    focal = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
