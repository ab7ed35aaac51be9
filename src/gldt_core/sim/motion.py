"""Where everything is in every frame: target and bird paths, attitudes, sizes, camera ego-motion.

Paths are simulated in *world* pixels (the view at zero camera offset) with a velocity controller
so turns take time, MOT-FLY style: long level passes, loops, hovering, sudden turns, dives,
crossings and near-overlaps between targets, and leaving the view then coming back. Everything is
precomputed for all frames from per-target random streams, which gives random access to any frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gldt_core.sim.airframes import Airframe, bird_model, build_airframe
from gldt_core.sim.spec import SceneSpec
from gldt_core.sim.style import STREAM_BIRD, STREAM_CAMERA, STREAM_TARGET, SceneStyle

PATTERNS = ("pass", "loop", "hover", "turns", "dive", "reenter")
FIXED_WING_PATTERNS = ("pass", "loop", "turns", "dive", "reenter")

#: Airframe colours (BGR). Seen against the sky a drone is mostly its shadowed underside, so
#: even white airframes show up mid-grey; dark ones dominate, as in the real clips.
DRONE_COLOURS = (
    (28, 28, 30),
    (45, 42, 40),
    (60, 60, 62),
    (35, 38, 45),
    (80, 80, 85),
    (110, 110, 115),
    (150, 152, 155),
    (40, 60, 150),
    (30, 35, 90),
)


@dataclass(frozen=True)
class Track:
    """One flying object over all frames (world px, airframe angles in radians)."""

    airframe: Airframe | None  # None for birds (their model changes with the wing beat)
    pattern: str
    centre: np.ndarray  # (F, 2) world px
    span: np.ndarray  # (F,) px
    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    bank: np.ndarray
    elevation: np.ndarray
    colour: tuple[int, int, int]
    behind_clouds: bool
    flap_phase: np.ndarray | None = None
    behind_terrain: bool = False  # far enough to pass behind the tree line / skyline

    def model(self, frame: int) -> Airframe:
        """The shape drawn in ``frame``: the fixed airframe, or a bird at its wing-beat phase."""
        if self.airframe is not None:
            return self.airframe
        assert self.flap_phase is not None, "a track without an airframe is a bird"
        return bird_model(float(self.flap_phase[frame]))


def camera_offsets(spec: SceneSpec, style: SceneStyle) -> np.ndarray:
    """Integer camera offsets (F, 2) within the margin: slow pan/tilt drift plus jitter.

    Integer offsets keep background crops exact copies; ground truth subtracts the same offsets,
    so boxes follow the ego-motion pixel for pixel.
    """
    rng = spec.rng(STREAM_CAMERA)
    times = np.arange(spec.frames) / spec.fps
    offsets = np.zeros((spec.frames, 2))
    mode = rng.choice(["tripod", "drift", "pan"], p=[0.2, 0.45, 0.35])
    for axis, margin in enumerate(style.margin):
        limit = 0.85 * margin
        if mode == "tripod":
            base = np.zeros_like(times)
        else:
            amplitude = rng.uniform(0.1, 0.6 if mode == "pan" else 0.3) * limit
            period = rng.uniform(4.0, 20.0)
            rate = rng.normal(0, 0.06 if axis == 0 else 0.02) * margin
            base = amplitude * np.sin(2 * np.pi * times / period + rng.uniform(0, 2 * np.pi))
            base = base + rate * times
            base = limit - np.abs((base + limit) % (4 * limit) - 2 * limit)  # fold into range
        sigma = rng.uniform(0.2, 2.5)
        jitter = np.zeros_like(times)
        shocks = rng.normal(0, sigma, size=len(times))
        for k in range(1, len(times)):
            jitter[k] = 0.6 * jitter[k - 1] + shocks[k]
        offsets[:, axis] = np.clip(base + jitter, -margin, margin)
    return np.rint(offsets).astype(np.int64)


def _steer(
    rng: np.random.Generator,
    spec: SceneSpec,
    pattern: str,
    fixed_wing: bool,
    start: np.ndarray,
    velocity: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate one path; returns centres and velocities (F, 2) in world px and px/s."""
    width, height = spec.size
    dt = 1.0 / spec.fps
    agility = rng.uniform(1.2, 2.5) if fixed_wing else rng.uniform(3.0, 8.0)
    speed = float(np.linalg.norm(velocity))
    heading = float(np.arctan2(velocity[1], velocity[0]))
    position = start.astype(float).copy()
    current = velocity.astype(float).copy()
    centres = np.zeros((spec.frames, 2))
    velocities = np.zeros((spec.frames, 2))
    wobble_period = rng.uniform(2.0, 6.0)
    wobble = rng.uniform(0.0, 0.03) * height
    loop_rate = rng.uniform(0.6, 1.6) * rng.choice([-1, 1])
    loop_radius = rng.uniform(0.05, 0.16) * width
    anchor = position.copy()
    next_turn = rng.exponential(1.5)
    dive_at = rng.uniform(0.5, 5.0)
    dive_len = rng.uniform(0.6, 1.6)
    outside_margin = rng.uniform(0.0, 0.06) * width
    if pattern == "reenter":  # fly well out of view before turning back in
        outside_margin = 0.08 * width + 2.0 * outside_margin
    returning = False
    for frame in range(spec.frames):
        t = frame * dt
        if pattern == "hover":
            desired = 2.0 * (anchor - position) + rng.normal(0, 0.01 * width, 2)
        elif pattern == "loop":
            angle = loop_rate * t
            tangent = np.array([-np.sin(angle), np.cos(angle)])
            desired = loop_radius * abs(loop_rate) * tangent * np.sign(loop_rate)
            desired = desired + 0.3 * speed * np.array([np.cos(heading), 0.0])
        else:
            if pattern == "turns" and t >= next_turn:
                heading += np.radians(rng.uniform(60, 150)) * rng.choice([-1, 1])
                next_turn = t + rng.exponential(1.5) + 0.3
            desired = speed * np.array([np.cos(heading), 0.6 * np.sin(heading)])
            desired[1] += wobble * 2 * np.pi / wobble_period * np.cos(2 * np.pi * t / wobble_period)
            if pattern == "dive" and dive_at <= t < dive_at + dive_len:
                desired[1] += 0.35 * height
            elif pattern == "dive" and dive_at + dive_len <= t < dive_at + 2 * dive_len:
                desired[1] -= 0.25 * height
        # Leaving the view: keep going a little, then head back in (re-entry, new crossings).
        out_x = position[0] < -outside_margin or position[0] > width + outside_margin
        out_y = position[1] < -outside_margin or position[1] > height + outside_margin
        if (out_x or out_y) and not returning:
            anchor = np.array([rng.uniform(0.2, 0.8) * width, rng.uniform(0.15, 0.7) * height])
            returning = True
        if returning:
            to_anchor = anchor - position
            heading = float(np.arctan2(to_anchor[1], to_anchor[0]))
            desired = max(speed, 0.05 * width) * to_anchor / max(np.linalg.norm(to_anchor), 1e-6)
            inside = 0.1 * width < position[0] < 0.9 * width and 0.1 * height < position[1] < 0.85 * height
            if inside or np.linalg.norm(to_anchor) < 0.05 * width:
                returning = False
                if pattern == "hover":
                    anchor = position.copy()
        gain = min(1.0, agility * dt)
        current = current + (desired - current) * gain
        position = position + current * dt
        centres[frame] = position
        velocities[frame] = current
    return centres, velocities


def _target_track(spec: SceneSpec, style: SceneStyle, index: int, lead: Track | None) -> Track:
    rng = spec.rng(STREAM_TARGET + index)
    width, height = spec.size
    kind = str(rng.choice(["quad", "quad", "hexa", "fixed"]))
    fixed_wing = kind == "fixed"
    pattern = str(rng.choice(FIXED_WING_PATTERNS if fixed_wing else PATTERNS))
    low, high = spec.span_range
    span0 = float(np.exp(rng.uniform(np.log(low), np.log(high))))
    speed = rng.uniform(0.03, 0.2) * width * (1.5 if fixed_wing else 1.0)
    heading = rng.uniform(-0.35, 0.35) + (np.pi if rng.random() < 0.5 else 0.0)
    velocity = speed * np.array([np.cos(heading), np.sin(heading)])
    if pattern != "hover" and rng.random() < 0.25:  # enter from the side it flies away from
        start_x = -0.05 * width if velocity[0] > 0 else 1.05 * width
    else:
        start_x = rng.uniform(0.1, 0.9) * width
    start = np.array([start_x, rng.uniform(0.1, 0.7) * height])
    meet = int(min(spec.frames - 1, rng.uniform(0.8, 4.0) * spec.fps))
    wants_crossing = rng.random() < 0.6
    if lead is not None and pattern in ("pass", "turns", "dive") and wants_crossing:
        # Aim at the lead target's position a few seconds ahead: a crossing / near-overlap.
        meeting_point = lead.centre[meet]
        if 0.05 * width < meeting_point[0] < 0.95 * width and 0.05 * height < meeting_point[1] < 0.9 * height:
            offset = rng.normal(0, 0.5) * span0
            start = meeting_point - velocity * meet / spec.fps + np.array([0.0, offset])
    centres, velocities = _steer(rng, spec, pattern, fixed_wing, start, velocity)

    t = np.arange(spec.frames) / spec.fps
    breathing = rng.uniform(0.0, 0.35) * np.sin(2 * np.pi * t / rng.uniform(4, 15) + rng.uniform(0, 6.3))
    span = np.clip(span0 * np.exp(breathing), low, high)
    vx, vy = velocities[:, 0], velocities[:, 1]
    elevation = np.full(spec.frames, rng.uniform(-0.45, 0.6))
    if fixed_wing:
        side_yaw = rng.uniform(-0.7, 0.7)
        facing_left = vx < 0
        yaw = np.where(facing_left, np.pi - side_yaw, side_yaw)
        pitch = np.clip(np.arctan2(-vy, np.abs(vx) + 1e-6), -1.2, 1.2)
        direction = np.unwrap(np.arctan2(vy, vx))
        turn_rate = np.gradient(direction) * spec.fps if spec.frames > 1 else np.zeros(1)
        roll = np.clip(0.35 * turn_rate, -1.0, 1.0)
        bank = np.zeros(spec.frames)
    else:
        yaw = rng.uniform(0, 2 * np.pi) + rng.normal(0, 0.25) * t
        pitch = np.zeros(spec.frames)
        roll = np.zeros(spec.frames)
        bank = np.clip(-0.25 * vx / np.maximum(span, 1.0) / 3.0, -0.5, 0.5)
    colour = DRONE_COLOURS[int(rng.integers(len(DRONE_COLOURS)))]
    behind = bool(0 < style.cloud_cover <= 0.55 and rng.random() < 0.4)
    airframe = build_airframe(kind, rng)
    behind_terrain = bool(style.terrain != "none" and rng.random() < 0.35)
    return Track(
        airframe=airframe,
        behind_terrain=behind_terrain,
        pattern=pattern,
        centre=centres,
        span=span,
        yaw=yaw,
        pitch=pitch,
        roll=roll,
        bank=bank,
        elevation=elevation,
        colour=colour,
        behind_clouds=behind,
    )


def target_tracks(spec: SceneSpec, style: SceneStyle) -> list[Track]:
    """All drone tracks of the scene (index i gets MOT id i + 1)."""
    tracks: list[Track] = []
    for index in range(spec.targets):
        tracks.append(_target_track(spec, style, index, tracks[0] if tracks else None))
    return tracks


def _bgr(values: np.ndarray) -> tuple[int, int, int]:
    """Three drawn channel values as a BGR colour tuple."""
    blue, green, red = (int(v) for v in values)
    return blue, green, red


def bird_tracks(spec: SceneSpec, style: SceneStyle) -> list[Track]:
    """Distractor birds: small, flapping, meandering (class 2 in the ground truth)."""
    tracks = []
    width, height = spec.size
    scale = height / 1080.0
    for index in range(style.birds):
        rng = spec.rng(STREAM_BIRD + index)
        heading = rng.uniform(-0.5, 0.5) + (np.pi if rng.random() < 0.5 else 0.0)
        speed = rng.uniform(0.04, 0.12) * width
        start = np.array([rng.uniform(0.05, 0.95) * width, rng.uniform(0.05, 0.75) * height])
        centres, velocities = _steer(
            rng, spec, "turns", False, start, speed * np.array([np.cos(heading), np.sin(heading)])
        )
        t = np.arange(spec.frames) / spec.fps
        span = np.full(spec.frames, rng.uniform(7.0, 24.0) * scale)
        beat = rng.uniform(3.0, 7.0)
        gliding = np.sin(2 * np.pi * t / rng.uniform(2, 5)) > 0.3
        flap = np.where(gliding, 0.2, np.sin(2 * np.pi * beat * t + rng.uniform(0, 6.3)) * np.pi / 2)
        vx = velocities[:, 0]
        tracks.append(
            Track(
                airframe=None,
                pattern="bird",
                centre=centres,
                span=span,
                yaw=np.where(vx < 0, np.pi, 0.0) + rng.uniform(-0.5, 0.5),
                pitch=np.clip(np.arctan2(-velocities[:, 1], np.abs(vx) + 1e-6), -0.8, 0.8),
                roll=np.zeros(spec.frames),
                bank=np.zeros(spec.frames),
                elevation=np.full(spec.frames, rng.uniform(-0.4, 0.3)),
                colour=_bgr(rng.integers(25, 70, size=3)),
                behind_clouds=False,
                flap_phase=flap,
            )
        )
    return tracks
