"""Procedural airframes (quadrotor, hexarotor, fixed-wing, bird) as 3-D parts, at any pose.

A model is a list of convex solids (drawn as the convex hull of their projected corners) and rods
(drawn as thick lines), in body axes x forward, y left, z up, scaled so the span is 1. Drawing the
hull of projected corners works at every attitude, including edge-on views where a flat polygon
would vanish. The ground-truth box is the extent of the same projected points, so box and pixels
come from one geometry.

View axes: X right, Y away from the camera, Z up; image u = X, v = -Z (orthographic: the targets
are far away compared with their size).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS = ("quad", "hexa", "fixed")


@dataclass(frozen=True)
class Part:
    """One drawable part: a convex solid (``radius`` 0) or a rod polyline (``radius`` > 0)."""

    points: np.ndarray  # (n, 3)
    shade: float  # brightness factor applied to the airframe colour
    alpha: float  # opacity (rotor discs are see-through blurs)
    radius: float = 0.0
    neutral: bool = False  # drawn grey whatever the airframe colour (spinning rotor blur)


@dataclass(frozen=True)
class Airframe:
    kind: str
    parts: tuple[Part, ...]

    def key_points(self) -> tuple[np.ndarray, np.ndarray]:
        """All points (P, 3) and the radius padding each one needs for the box (P,)."""
        points = np.concatenate([p.points for p in self.parts])
        pads = np.concatenate([np.full(len(p.points), p.radius) for p in self.parts])
        return points, pads


def _box(center: tuple[float, float, float], size: tuple[float, float, float]) -> np.ndarray:
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    return np.asarray(center, float) + 0.5 * signs * np.asarray(size, float)


def _disc(center: tuple[float, float, float], radius: float, thickness: float, n: int = 12) -> np.ndarray:
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(n)], axis=1)
    offset = np.array([0.0, 0.0, thickness / 2])
    return np.concatenate([ring + offset, ring - offset]) + np.asarray(center, float)


def _normalised(kind: str, parts: list[Part]) -> Airframe:
    points = np.concatenate([p.points for p in parts])
    span = max(np.ptp(points[:, 0]), np.ptp(points[:, 1]))
    centre = np.array(
        [points[:, 0].min() + np.ptp(points[:, 0]) / 2, points[:, 1].min() + np.ptp(points[:, 1]) / 2, 0.0]
    )
    return Airframe(
        kind,
        tuple(Part((p.points - centre) / span, p.shade, p.alpha, p.radius / span, p.neutral) for p in parts),
    )


def _multirotor(arms: int, rng: np.random.Generator) -> Airframe:
    arm = rng.uniform(0.3, 0.42)
    rotor = rng.uniform(0.12, 0.18) if arms == 4 else rng.uniform(0.1, 0.14)
    body = rng.uniform(0.2, 0.3)
    parts = [
        Part(_box((0, 0, 0.01), (body, body * 0.7, 0.09)), 1.0, 1.0),
        Part(_box((0.02, 0, 0.07), (body * 0.55, body * 0.4, 0.04)), 0.85, 1.0),
        Part(_box((body * 0.45, 0, -0.06), (0.06, 0.06, 0.06)), 0.55, 1.0),
    ]
    start = 45.0 if arms == 4 else 30.0
    for k in range(arms):
        angle = np.radians(start + k * 360.0 / arms)
        tip = (arm * np.cos(angle), arm * np.sin(angle), 0.03)
        root = (0.35 * body * np.cos(angle), 0.3 * body * np.sin(angle), 0.02)
        parts.append(Part(np.array([root, tip]), 1.0, 1.0, 0.022))
        parts.append(Part(_box(tip, (0.06, 0.06, 0.07)), 0.8, 1.0))
        parts.append(Part(_disc((tip[0], tip[1], 0.08), rotor, 0.01), 1.0, 0.28, neutral=True))
    for sx in (-1, 1):
        for sy in (-1, 1):
            leg = np.array([[sx * 0.05, sy * 0.07, -0.03], [sx * 0.065, sy * 0.09, -0.11]])
            parts.append(Part(leg, 0.9, 1.0, 0.008))
    return _normalised("quad" if arms == 4 else "hexa", parts)


def _fixed_wing(rng: np.random.Generator) -> Airframe:
    length = rng.uniform(0.55, 0.85)
    chord = rng.uniform(0.1, 0.18)
    tail = rng.uniform(0.25, 0.4)
    parts = [
        Part(_box((0.0, 0, 0), (length, 0.08, 0.09)), 1.0, 1.0),
        Part(_box((length * 0.45, 0, -0.005), (0.1, 0.06, 0.07)), 0.9, 1.0),
        Part(_box((length * 0.12, 0, 0.035), (chord, 1.0, 0.018)), 1.05, 1.0),
        Part(_box((-length * 0.45, 0, 0.02), (0.08, tail, 0.014)), 1.05, 1.0),
        Part(_box((-length * 0.46, 0, 0.085), (0.1, 0.012, 0.13)), 0.95, 1.0),
    ]
    prop = _disc((0, 0, 0), 0.08, 0.005)[:, [2, 0, 1]] + np.array([length * 0.52, 0, 0])
    parts.append(Part(prop, 1.0, 0.28, neutral=True))
    return _normalised("fixed", parts)


def build_airframe(kind: str, rng: np.random.Generator) -> Airframe:
    """A randomly proportioned airframe of ``kind`` (``quad``, ``hexa`` or ``fixed``)."""
    if kind == "quad":
        return _multirotor(4, rng)
    if kind == "hexa":
        return _multirotor(6, rng)
    if kind == "fixed":
        return _fixed_wing(rng)
    raise ValueError(f"unknown airframe kind {kind!r}; expected one of {KINDS}")


def bird_model(flap_phase: float) -> Airframe:
    """A bird with its wings at ``flap_phase`` (radians) of the wing beat; span 1 at wings level."""
    lift = np.sin(flap_phase)
    parts = [
        Part(_box((0, 0, 0), (0.34, 0.07, 0.07)), 1.0, 1.0),
        Part(_box((0.2, 0, 0.01), (0.08, 0.05, 0.05)), 0.9, 1.0),
        Part(_box((-0.22, 0, 0), (0.12, 0.09, 0.012)), 1.0, 1.0),
    ]
    for side in (-1, 1):
        wing = np.array(
            [[0.02, side * 0.03, 0.01], [0.0, side * 0.25, 0.14 * lift], [-0.07, side * 0.5, 0.32 * lift - 0.04]]
        )
        parts.append(Part(wing, 1.0, 1.0, 0.035))
    return Airframe("bird", tuple(parts))


def rotation_matrices(
    yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray, bank: np.ndarray, elevation: np.ndarray
) -> np.ndarray:
    """Body-to-view rotations (F, 3, 3): ``Rx(elev) Ry(bank) Rz(yaw) Ry(-pitch) Rx(roll)``.

    ``bank`` tilts the airframe in the image plane (multirotors leaning into their motion),
    ``elevation`` is how far the camera looks down on the target (negative: from below).
    """

    def rx(a: np.ndarray) -> np.ndarray:
        c, s = np.cos(a), np.sin(a)
        o, z = np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)

    def ry(a: np.ndarray) -> np.ndarray:
        c, s = np.cos(a), np.sin(a)
        o, z = np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)

    def rz(a: np.ndarray) -> np.ndarray:
        c, s = np.cos(a), np.sin(a)
        o, z = np.ones_like(a), np.zeros_like(a)
        return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)

    arrays = [np.asarray(a, float) for a in (yaw, pitch, roll, bank, elevation)]
    yaw, pitch, roll, bank, elevation = np.broadcast_arrays(*arrays)
    return rx(elevation) @ ry(bank) @ rz(yaw) @ ry(-pitch) @ rx(roll)


def project(points: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Project body points (P, 3) with rotations (..., 3, 3) to image offsets (..., P, 2)."""
    rotated = np.einsum("...ij,pj->...pi", rotations, points)
    return np.stack([rotated[..., 0], -rotated[..., 2]], axis=-1)


def box_extents(airframe: Airframe, rotations: np.ndarray) -> np.ndarray:
    """Image-plane extents (..., 4) = (u_min, v_min, u_max, v_max) of a unit-span airframe."""
    points, pads = airframe.key_points()
    uv = project(points, rotations)
    low = (uv - pads[:, None]).min(axis=-2)
    high = (uv + pads[:, None]).max(axis=-2)
    return np.concatenate([low, high], axis=-1)
