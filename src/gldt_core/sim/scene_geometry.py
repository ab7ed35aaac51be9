"""Scene geometry without pixels: camera offsets, tracks, boxes and visibilities of every frame.

:class:`SceneGeometry` is shared by :func:`scene_ground_truth` (which stops here, so it is fast)
and the renderer (which draws exactly these objects), which is how the two agree exactly.

Paths are simulated for a whole *shot* at once (:mod:`gldt_core.sim.motion`), which costs memory
and time in proportion to its length; a scene longer than :data:`SHOT_FRAMES` is a sequence of
shots of the same sky, simulated one at a time when a frame of theirs is asked for, so reading a
few frames of a scene of a billion frames costs what reading a 10-minute scene does. At each cut
the camera and every object start over on new paths (drones keep their ids 1..targets, birds
theirs). A scene of up to :data:`SHOT_FRAMES` frames is one shot, exactly as before shots existed,
and the first shot of a longer scene is the scene of :data:`SHOT_FRAMES` frames with the same
spec.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Unpack

import numpy as np

from gldt_core.sim.airframes import box_extents, rotation_matrices
from gldt_core.sim.background import canvas_size, cloud_field, ridge_profile, sample_cloud, terrain_visibility
from gldt_core.sim.motion import Track, bird_tracks, camera_offsets, target_tracks
from gldt_core.sim.spec import BIRD_ID_BASE, CLASS_BIRD, CLASS_DRONE, SceneSpec, SpecExtras
from gldt_core.sim.style import SceneStyle, scene_style

#: Longest stretch of a scene simulated at once: 10 minutes at 30 fps (about a second to simulate
#: and a few MB of paths). Longer scenes are cut into shots of this many frames.
SHOT_FRAMES = 18_000

#: Random stream key that derives the seed of a long scene's shot k >= 1 from the scene's seed.
STREAM_SHOT = 90


@dataclass
class ObjectState:
    """One object in one frame: what the renderer draws and what the ground truth records."""

    track_id: int
    class_id: int
    track: Track
    frame: int  # index into ``track``'s arrays: the frame within its shot (the scene's, for one shot)
    centre: np.ndarray  # view px (after ego-motion)
    rotation: np.ndarray  # (3, 3)
    box: np.ndarray  # unclipped x1, y1, x2, y2 in view px
    occlusion: float  # cloud opacity in front of it (0 when in front of the clouds)
    visibility: float  # (1 - occlusion) * unhidden-by-terrain fraction * fraction inside the view


class Shot:
    """The paths of one shot: camera offsets (F, 2), drone and bird tracks over its F frames."""

    def __init__(self, spec: SceneSpec, style: SceneStyle) -> None:
        self.frames = spec.frames
        self.camera = camera_offsets(spec, style)
        self.targets = target_tracks(spec, style)
        self.birds = bird_tracks(spec, style)

    @cached_property
    def target_boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per target: rotations (F, 3, 3) and world boxes (F, 4)."""
        result = []
        for track in self.targets:
            assert track.airframe is not None, "drone targets carry a fixed airframe"
            rotations = rotation_matrices(track.yaw, track.pitch, track.roll, track.bank, track.elevation)
            extents = box_extents(track.airframe, rotations) * track.span[:, None]
            boxes = extents + np.tile(track.centre, 2)
            result.append((rotations, boxes))
        return result


class SceneGeometry:
    """Everything about a scene except pixels; cheap (no image buffers), and its memory does not
    grow with the scene's length (one shot of paths is kept at a time)."""

    def __init__(self, spec: SceneSpec) -> None:
        self.spec = spec
        self.style: SceneStyle = scene_style(spec)
        self.clouds = cloud_field(spec, self.style)
        self.canvas_wh = canvas_size(spec, self.style)
        self.ridge, _ = ridge_profile(spec, self.style)
        self._shot: tuple[int, Shot] | None = None

    def shot(self, frame: int) -> tuple[Shot, int]:
        """The shot holding ``frame`` (0-based) and the frame's index within it."""
        number, local = divmod(int(frame), SHOT_FRAMES)
        if self._shot is None or self._shot[0] != number:
            self._shot = (number, Shot(self._shot_spec(number), self.style))
        return self._shot[1], local

    def _shot_spec(self, number: int) -> SceneSpec:
        """The spec whose paths shot ``number`` shows: the scene's own for a one-shot scene; for a
        longer one, its length and (from the second shot on) a seed derived from the scene's."""
        spec = self.spec
        if spec.frames <= SHOT_FRAMES:
            return spec
        length = min(SHOT_FRAMES, spec.frames - number * SHOT_FRAMES)
        if number == 0:
            return spec.with_(frames=length)
        seed = int(spec.rng(STREAM_SHOT, number).integers(0, 2**31))
        return spec.with_(frames=length, seed=seed)

    @property
    def camera(self) -> np.ndarray:
        """Camera offsets (F, 2) of the first shot (the whole scene unless it is longer than
        :data:`SHOT_FRAMES`)."""
        return self.shot(0)[0].camera

    @property
    def targets(self) -> list[Track]:
        """Drone tracks of the first shot (see :attr:`camera`)."""
        return self.shot(0)[0].targets

    @property
    def birds(self) -> list[Track]:
        """Bird tracks of the first shot (see :attr:`camera`)."""
        return self.shot(0)[0].birds

    def objects(self, frame: int) -> list[ObjectState]:
        """Objects whose box overlaps the view in ``frame`` (0-based), drones then birds; each
        state's ``frame`` is its index within the shot (:meth:`shot`)."""
        spec = self.spec
        if not 0 <= frame < spec.frames:
            raise ValueError(f"frame {frame} out of range 0..{spec.frames - 1}")
        shot, local = self.shot(frame)
        shift = np.tile(shot.camera[local].astype(float), 2)
        states: list[ObjectState] = []
        for index, track in enumerate(shot.targets):
            rotations, boxes = shot.target_boxes[index]
            occlusion = 0.0
            if track.behind_clouds:
                canvas_xy = track.centre[local] + np.array(self.style.margin, float)
                occlusion = float(sample_cloud(self.clouds, self.canvas_wh, canvas_xy[0], canvas_xy[1]))
            terrain = 1.0
            if track.behind_terrain:
                canvas_box = boxes[local] + np.tile(np.array(self.style.margin, float), 2)
                terrain = terrain_visibility(self.ridge, canvas_box)
            state = self._state(
                index + 1,
                CLASS_DRONE,
                track,
                local,
                shot.camera,
                rotations[local],
                boxes[local] - shift,
                occlusion,
                terrain,
            )
            if state is not None:
                states.append(state)
        for index, track in enumerate(shot.birds):
            model = track.model(local)
            rotation = rotation_matrices(
                track.yaw[local], track.pitch[local], track.roll[local], track.bank[local], track.elevation[local]
            )
            box = box_extents(model, rotation) * track.span[local] + np.tile(track.centre[local], 2)
            state = self._state(BIRD_ID_BASE + index, CLASS_BIRD, track, local, shot.camera, rotation, box - shift, 0.0)
            if state is not None:
                states.append(state)
        return states

    def _state(
        self,
        track_id: int,
        class_id: int,
        track: Track,
        frame: int,
        camera: np.ndarray,
        rotation: np.ndarray,
        box: np.ndarray,
        occlusion: float,
        terrain: float = 1.0,
    ) -> ObjectState | None:
        width, height = self.spec.size
        clipped = np.array([max(box[0], 0.0), max(box[1], 0.0), min(box[2], width), min(box[3], height)])
        if clipped[2] - clipped[0] < 1.0 or clipped[3] - clipped[1] < 1.0:
            return None
        area = max((box[2] - box[0]) * (box[3] - box[1]), 1e-9)
        inside = (clipped[2] - clipped[0]) * (clipped[3] - clipped[1]) / area
        centre = track.centre[frame] - camera[frame]
        return ObjectState(
            track_id, class_id, track, frame, centre, rotation, box, occlusion, (1.0 - occlusion) * terrain * inside
        )

    def ground_truth(self, frame: int) -> np.ndarray:
        """MOT rows (K, 10) of ``frame`` (0-based): boxes clipped to the view, 2-decimal px."""
        return rows_from_states(self.objects(frame), frame, self.spec.size)

    def all_ground_truth(self) -> np.ndarray:
        """MOT rows (N, 10) of every frame of the scene, in frame order."""
        tables = [self.ground_truth(k) for k in range(self.spec.frames)]
        tables = [t for t in tables if len(t)]
        return np.concatenate(tables) if tables else np.zeros((0, 10))


def rows_from_states(states: list[ObjectState], frame: int, size: tuple[int, int]) -> np.ndarray:
    """MOT rows for object states: ``frame+1, id, x, y, w, h, 1, class, visibility, -1``."""
    width, height = size
    rows = []
    for state in states:
        x1 = round(max(state.box[0], 0.0), 2)
        y1 = round(max(state.box[1], 0.0), 2)
        x2 = round(min(state.box[2], float(width)), 2)
        y2 = round(min(state.box[3], float(height)), 2)
        rows.append(
            [
                frame + 1,
                state.track_id,
                x1,
                y1,
                round(x2 - x1, 2),
                round(y2 - y1, 2),
                1,
                state.class_id,
                round(state.visibility, 3),
                -1,
            ]
        )
    if not rows:
        return np.zeros((0, 10))
    return np.asarray(rows, dtype=np.float64)


def scene_ground_truth(
    seed: int,
    frames: int,
    size: tuple[int, int] = (1920, 1080),
    targets: int = 3,
    fps: float = 30.0,
    **spec_fields: Unpack[SpecExtras],
) -> np.ndarray:
    """The MOT ground truth (N, 10) the renderer draws for these arguments, without rendering.

    Columns: frame (1-based), id, x, y, w, h (top-left, px, clipped to the view), considered (1),
    class (1 drone, 2 bird: distractor, ids from 1001), visibility (0..1: cloud occlusion times
    the fraction inside the view), -1. Drones have ids 1..targets. Extra keyword arguments are
    :class:`SceneSpec` fields (``target_size``, ``birds``, ...). Filter ``gt[:, 7] == 1`` for
    drones only.
    """
    spec = SceneSpec(seed=seed, frames=frames, size=size, targets=targets, fps=fps, **spec_fields)
    return SceneGeometry(spec).all_ground_truth()
