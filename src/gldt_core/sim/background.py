"""The scene's background canvas: sky gradient, clouds, sun glare and the ground below the horizon.

The canvas is rendered once per scene, larger than the view by the ego-motion margin, and each
frame is a crop of it at the camera offset, which keeps a 1080p frame cheap to render.
The cloud opacity is defined on a coarse grid (:func:`cloud_field`) so the ground truth can read
a target's cloud occlusion without rendering any pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from gldt_core.sim.noise import fractal_noise, noise_1d
from gldt_core.sim.spec import SceneSpec
from gldt_core.sim.style import STREAM_CLOUDS, STREAM_RIDGE, STREAM_TEXTURE, SceneStyle

CLOUD_DOWNSCALE = 8


def canvas_size(spec: SceneSpec, style: SceneStyle) -> tuple[int, int]:
    """(width, height) of the canvas: the view plus the ego-motion margin on each side."""
    return spec.width + 2 * style.margin[0], spec.height + 2 * style.margin[1]


def cloud_field(spec: SceneSpec, style: SceneStyle) -> np.ndarray:
    """Cloud opacity in [0, 1] on a grid ``CLOUD_DOWNSCALE`` times coarser than the canvas."""
    canvas_w, canvas_h = canvas_size(spec, style)
    low_w = -(-canvas_w // CLOUD_DOWNSCALE)
    low_h = -(-canvas_h // CLOUD_DOWNSCALE)
    rng = spec.rng(STREAM_CLOUDS)
    field = fractal_noise(rng, (low_h, low_w), float(rng.uniform(2.0, 5.0)), 4, 0.55)
    if style.cloud_cover <= 0.0:
        return np.zeros_like(field)
    threshold = float(np.quantile(field, 1.0 - style.cloud_cover))
    alpha = np.clip((field - threshold) / 0.16, 0.0, 1.0)
    alpha = alpha * alpha * (3.0 - 2.0 * alpha) * style.cloud_opacity
    rows = (np.arange(low_h, dtype=np.float32) + 0.5) * (canvas_h / low_h) - 0.5
    horizon_canvas = style.horizon_y + style.margin[1]
    fade = np.clip((horizon_canvas - rows) / (0.08 * spec.height), 0.0, 1.0)
    return (alpha * fade[:, None]).astype(np.float32)


def sample_cloud(field: np.ndarray, canvas_wh: tuple[int, int], x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear cloud opacity at canvas points (x, y), matching cv2's resize of ``field``."""
    low_h, low_w = field.shape
    gx = (np.asarray(x, np.float64) + 0.5) * (low_w / canvas_wh[0]) - 0.5
    gy = (np.asarray(y, np.float64) + 0.5) * (low_h / canvas_wh[1]) - 0.5
    gx = np.clip(gx, 0.0, low_w - 1.0)
    gy = np.clip(gy, 0.0, low_h - 1.0)
    x0 = np.minimum(np.floor(gx).astype(int), low_w - 2 if low_w > 1 else 0)
    y0 = np.minimum(np.floor(gy).astype(int), low_h - 2 if low_h > 1 else 0)
    x1 = np.minimum(x0 + 1, low_w - 1)
    y1 = np.minimum(y0 + 1, low_h - 1)
    fx = gx - x0
    fy = gy - y0
    top = field[y0, x0] * (1 - fx) + field[y0, x1] * fx
    bottom = field[y1, x0] * (1 - fx) + field[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def render_canvas(spec: SceneSpec, style: SceneStyle, clouds: np.ndarray) -> np.ndarray:
    """Render the background canvas (BGR uint8, canvas size).

    Smooth parts (gradient, mottle, glare) are computed at quarter resolution and upsampled;
    blending uses ``cv2.blendLinear`` so even a 2k canvas is cheap.
    """
    canvas_w, canvas_h = canvas_size(spec, style)
    rng = spec.rng(STREAM_TEXTURE)
    margin_x, margin_y = style.margin
    horizon_canvas = style.horizon_y + margin_y
    zenith = np.array(style.zenith, np.float32)
    horizon = np.array(style.horizon_color, np.float32)

    low = 4
    low_w, low_h = -(-canvas_w // low), -(-canvas_h // low)
    rows = (np.arange(low_h, dtype=np.float32) + 0.5) * low
    t = np.clip(rows / max(horizon_canvas, 1.0), 0.0, 1.0) ** 1.6
    sky = zenith[None, None, :] * (1 - t[:, None, None]) + horizon[None, None, :] * t[:, None, None]
    sky = np.repeat(sky, low_w, axis=1).astype(np.float32)
    sky += (fractal_noise(rng, (low_h, low_w), 3.0, 3)[..., None] - 0.5) * 8.0
    if style.sun_strength > 0.02:
        gx = (np.arange(low_w, dtype=np.float32) + 0.5) * low - (style.sun_xy[0] + margin_x)
        gy = (np.arange(low_h, dtype=np.float32) + 0.5) * low - (style.sun_xy[1] + margin_y)
        radius = np.sqrt(gx[None, :] ** 2 + gy[:, None] ** 2) / spec.width
        glow = 0.6 * np.exp(-((radius / 0.3) ** 2)) + 0.5 * np.exp(-radius / 0.03)
        veil = np.clip(style.sun_strength * glow, 0, 1).astype(np.float32)[..., None]
        sun_color = np.array([225.0, 245.0, 255.0], np.float32)
        sky = sky * (1 - veil) + sun_color * veil
    if style.vignette > 0:  # lens fall-off, on the sky layer (smooth, so at low resolution)
        vx = np.linspace(-1, 1, low_w, dtype=np.float32) * (canvas_w / spec.width)
        vy = np.linspace(-1, 1, low_h, dtype=np.float32) * (canvas_h / spec.height)
        falloff = np.clip(1.0 - style.vignette * 0.5 * (vx[None, :] ** 2 + vy[:, None] ** 2), 0.5, 1.0)
        sky *= falloff[..., None]
    image = cv2.resize(sky, (canvas_w, canvas_h), interpolation=cv2.INTER_LINEAR)

    # Clouds: coarse opacity from the shared field, crisped by fine texture at the edges.
    # Shading is computed at half resolution (it is smooth) and upsampled once.
    if clouds.any():
        half_w, half_h = canvas_w // 2, canvas_h // 2
        texture = fractal_noise(rng, (half_h, half_w), 8.0, 4, 0.5)
        alpha = cv2.resize(clouds, (half_w, half_h), interpolation=cv2.INTER_LINEAR)
        alpha = np.clip(alpha * (0.75 + 0.5 * texture), 0.0, 1.0)
        core = cv2.resize(cv2.GaussianBlur(clouds, (0, 0), 3), (half_w, half_h))
        brightest = float(max(style.zenith + style.horizon_color))
        level = min(brightest + 18.0, 252.0)
        shade: np.ndarray = ((0.84 + 0.22 * texture - 0.2 * core) * level).astype(np.float32)
        alpha = cv2.resize(alpha.astype(np.float32), (canvas_w, canvas_h), interpolation=cv2.INTER_LINEAR)
        shade = cv2.resize(shade, (canvas_w, canvas_h), interpolation=cv2.INTER_LINEAR)
        cloud_rgb = cv2.merge([shade, shade, shade])
        image = cv2.blendLinear(image, cloud_rgb, 1.0 - alpha, alpha)

    if style.terrain != "none" and horizon_canvas < canvas_h + 0.3 * spec.height:
        image = _draw_ground(image, spec, style, rng, horizon_canvas)

    return cv2.convertScaleAbs(image)


#: Ground colour (BGR) and texture cell size (px at 1080p) of each terrain type.
TERRAIN_LOOKS = {
    "treeline": ((38.0, 62.0, 40.0), 6.0),
    "terrain": ((62.0, 95.0, 88.0), 25.0),
    "desert": ((130.0, 165.0, 190.0), 60.0),
    "urban": ((95.0, 98.0, 104.0), 40.0),
}


def ridge_profile(spec: SceneSpec, style: SceneStyle) -> tuple[np.ndarray, np.ndarray]:
    """Canvas row of the skyline for every canvas column, and per-column shade offsets.

    Drawn from its own stream because the ground truth needs it too: targets flying behind the
    tree line or the buildings are hidden by it.
    """
    canvas_w, _ = canvas_size(spec, style)
    horizon_canvas = style.horizon_y + style.margin[1]
    rng = spec.rng(STREAM_RIDGE)
    scale = spec.height / 1080.0
    shades = np.zeros(canvas_w)
    if style.terrain == "none":
        return np.full(canvas_w, np.inf), shades
    if style.terrain == "treeline":
        crowns = noise_1d(rng, canvas_w, canvas_w / (14.0 * scale), 3)
        hills = noise_1d(rng, canvas_w, 3.0, 2)
        profile = 25 * scale * hills + 38 * scale * crowns**1.5
    elif style.terrain == "terrain":
        profile = 60 * scale * noise_1d(rng, canvas_w, 4.0, 4)
    elif style.terrain == "desert":
        profile = 30 * scale * noise_1d(rng, canvas_w, 2.5, 3)
    else:  # urban skyline
        profile = np.zeros(canvas_w)
        x = 0
        while x < canvas_w:
            width = int(rng.uniform(20, 110) * scale) + 2
            profile[x : x + width] = rng.uniform(5, 70) * scale * rng.random() ** 0.5
            shades[x : x + width] = rng.uniform(-25, 25)
            x += width
    return horizon_canvas - profile, shades


def terrain_visibility(ridge: np.ndarray, box: np.ndarray) -> float:
    """Fraction of a canvas box (x1, y1, x2, y2) above the skyline (column by column)."""
    x1, y1, x2, y2 = box
    height = y2 - y1
    if height <= 0 or not np.isfinite(ridge).any():
        return 1.0
    columns = np.arange(max(int(np.floor(x1)), 0), min(int(np.ceil(x2)), len(ridge)))
    if len(columns) == 0:
        return 1.0
    visible_rows = np.clip(ridge[columns] - y1, 0.0, height)
    return float(visible_rows.mean() / height)


def _draw_ground(
    image: np.ndarray,
    spec: SceneSpec,
    style: SceneStyle,
    rng: np.random.Generator,
    horizon_canvas: float,
) -> np.ndarray:
    """Paint tree line, hills, desert or a city skyline below the horizon, hazed with distance."""
    canvas_h, canvas_w = image.shape[:2]
    scale = spec.height / 1080.0
    columns = np.arange(canvas_w)
    terrain_bgr, detail_cells = TERRAIN_LOOKS[style.terrain]
    detail_cells = canvas_w / (detail_cells * scale)
    colour = np.array(terrain_bgr)
    ridge, shades = ridge_profile(spec, style)
    top = int(max(0, np.floor(ridge.min())))
    if top >= canvas_h:
        return image
    band = image[top:]
    rows = np.arange(top, canvas_h, dtype=np.float32)[:, None]
    coverage = np.clip(rows - ridge[None, :].astype(np.float32) + 0.5, 0.0, 1.0)
    band_h = canvas_h - top
    detail = cv2.resize(
        fractal_noise(rng, (max(2, band_h // 2), max(2, canvas_w // 2)), detail_cells / 2, 3, 0.6),
        (canvas_w, band_h),
    )
    contrast = 0.35 if style.terrain == "urban" else 0.6
    factor = (1.0 - contrast / 2) + contrast * detail
    ground: np.ndarray = cv2.merge([(factor * float(c)).astype(np.float32) for c in colour])
    if style.terrain == "treeline":
        # Trunks and crowns: noise stretched vertically, so the tree band reads as many trees.
        trunks = cv2.resize(
            fractal_noise(rng, (max(2, band_h // 16), max(2, canvas_w // 2)), canvas_w / (5.0 * scale), 2, 0.6),
            (canvas_w, band_h),
        )
        ground *= (0.7 + 0.6 * trunks)[..., None]
    if style.terrain == "urban":
        ground += shades[None, :, None].astype(np.float32)
        windows = ((columns // max(2, int(6 * scale))) % 2 == 0)[None, :] & (
            (np.arange(band_h)[:, None] // max(2, int(8 * scale))) % 2 == 0
        )
        ground += (10.0 * (windows & (detail > 0.6))).astype(np.float32)[..., None]
    if style.terrain in ("treeline", "terrain", "desert", "urban"):
        # Fields in front of the horizon: horizontal streaks in a green, dry or sandy tone.
        field_colours = {
            "treeline": [(55.0, 115.0, 75.0), (70.0, 120.0, 150.0)],
            "terrain": [(60.0, 120.0, 95.0), (75.0, 125.0, 140.0)],
            "desert": [(120.0, 160.0, 190.0), (105.0, 145.0, 175.0)],
            "urban": [(80.0, 100.0, 95.0), (85.0, 88.0, 92.0)],
        }[style.terrain]
        field_colour = field_colours[int(rng.integers(len(field_colours)))]
        streaks = cv2.resize(
            fractal_noise(rng, (max(2, band_h // 2), max(2, canvas_w // 24)), canvas_w / (200.0 * scale), 3, 0.6),
            (canvas_w, band_h),
        )
        field = cv2.merge([((0.75 + 0.5 * streaks) * c).astype(np.float32) for c in field_colour])
        field_start = horizon_canvas + rng.uniform(4.0, 30.0) * scale
        in_field = np.clip(rows - field_start, 0.0, 1.0).astype(np.float32)
        in_field = np.repeat(in_field, canvas_w, axis=1)
        ground = cv2.blendLinear(ground.astype(np.float32), field, 1.0 - in_field, in_field)
    depth = np.clip((rows - horizon_canvas) / (0.35 * spec.height), 0.0, 1.0)
    haze = np.repeat((0.4 * (1 - depth) ** 2).astype(np.float32), canvas_w, axis=1)
    horizon_img = np.empty_like(ground)
    horizon_img[:] = np.array(style.horizon_color, np.float32)
    ground = cv2.blendLinear(ground, horizon_img, 1.0 - haze, haze)
    coverage = coverage.astype(np.float32)
    image[top:] = cv2.blendLinear(np.ascontiguousarray(band), ground.astype(np.float32), 1.0 - coverage, coverage)
    return image
