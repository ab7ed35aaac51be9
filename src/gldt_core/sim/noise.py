"""Smooth random fields (value noise summed over octaves), the texture source of sky and ground."""

from __future__ import annotations

import cv2
import numpy as np


def fractal_noise(
    rng: np.random.Generator,
    shape: tuple[int, int],
    base_cells: float,
    octaves: int,
    persistence: float = 0.5,
) -> np.ndarray:
    """A float32 field of ``shape`` in [0, 1]: ``octaves`` random grids upsampled and summed.

    ``base_cells`` is how many blobs span the width at the coarsest octave. Upsampling small grids
    with cv2 is what makes a 2k field cheap, where a Perlin loop in Python would not be.
    """
    height, width = shape
    total = np.zeros((height, width), np.float32)
    amplitude = 1.0
    cells = float(base_cells)
    for _ in range(octaves):
        grid_w = max(2, int(np.ceil(cells)) + 2)
        grid_h = max(2, int(np.ceil(cells * height / max(width, 1))) + 2)
        grid = rng.random((grid_h, grid_w), dtype=np.float32)
        total += amplitude * cv2.resize(grid, (width, height), interpolation=cv2.INTER_CUBIC)
        amplitude *= persistence
        cells *= 2.0
    low, high = float(total.min()), float(total.max())
    return (total - low) / max(high - low, 1e-6)


def noise_1d(rng: np.random.Generator, length: int, base_cells: float, octaves: int) -> np.ndarray:
    """A 1-D profile in [0, 1] (ridge lines of terrain and tree lines)."""
    return fractal_noise(rng, (1, length), base_cells, octaves)[0]
