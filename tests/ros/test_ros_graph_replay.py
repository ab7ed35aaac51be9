"""The ROS graph replays each sample bag in lockstep into exactly the offline GL-DT system's tracks.

This is the contract that lets everything be developed and measured offline: the graph's nodes,
each in its own process, exchanging gldt_msgs over DDS, must give the same identities and boxes
(within 1e-4 px) as ``GLDTSystem`` run in one process on the same bag - the code path of
``gldt run --bag``. The tracks must also meet a MOTA floor against the bag's ground truth.
"""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

import numpy as np
import pytest

from support import PIPELINE, REPO_ROOT, isolated_ros_env

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

BAGS = sorted(path for path in (REPO_ROOT / "bags").iterdir() if (path / "metadata.yaml").is_file())

#: Lowest MOTA (drones only) a sample bag's tracks must reach: a floor below what the offline run
#: reaches on the real clip (docs/results.md), so that only a real regression trips it. The
#: synthetic 1080p bag has none: the shipped global detector, trained briefly on CPU, does not
#: find its 5-14 px targets yet, so there it checks equivalence only.
MOTA_FLOOR = {"halmstad_v_drone_001": 0.90}


@functools.cache
def offline_run(bag: Path) -> tuple[np.ndarray, np.ndarray | None, dict[int, np.ndarray]]:
    """What `gldt run --bag` computes, at full precision: tracks, ground truth (None for a bag
    without any), detections per frame."""
    from gldt_core.io.sources import open_source
    from gldt_core.system.config import load_config
    from gldt_core.system.gldt_system import GLDTSystem
    from gldt_core.system.runner import run_frames

    system = GLDTSystem(load_config(None))
    detections: dict[int, np.ndarray] = {}

    def keep_detections(frame, _tracks) -> None:
        detections[int(frame.index)] = system.state.detections.copy()

    result = run_frames(system, open_source(str(bag)), on_frame=keep_detections, collect_ground_truth=True)
    return result.rows, result.ground_truth, detections


def offline_rows(bag: Path) -> tuple[np.ndarray, np.ndarray | None]:
    rows, ground_truth, _ = offline_run(bag)
    return rows, ground_truth


#: (bag, how the nodes share processes): every bag through `pipeline`'s default layout (grouped), and
#: the real bag also through one process per node (`--processes per-node`), through one process
#: for all five, the global detector on its worker thread (`--processes one-process`), and through
#: all nodes in `pipeline`'s own process (`--in-process`), which must give the same tracks.
REPLAYS = [(bag, "default") for bag in BAGS] + [
    (bag, placement)
    for bag in BAGS
    if bag.name in MOTA_FLOOR
    for placement in ("per-node", "one-process", "in-process")
]
PLACEMENT_ARGS = {
    "default": [],
    "per-node": ["--processes", "per-node"],
    "one-process": ["--processes", "one-process"],
    "in-process": ["--in-process"],
}


@pytest.fixture(
    scope="module",
    params=REPLAYS,
    ids=[bag.name + ("" if placement == "default" else f"-{placement}") for bag, placement in REPLAYS],
)
def replay(request, tmp_path_factory):
    bag, placement = request.param
    record = tmp_path_factory.mktemp(bag.name) / "graph.mcap"
    completed = subprocess.run(
        [str(PIPELINE), "--bag", str(bag), "--lockstep", "--record", str(record), *PLACEMENT_ARGS[placement]],
        capture_output=True,
        text=True,
        timeout=600,
        env=isolated_ros_env(),
    )
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    from gldt_core.io.recording import iter_recorded, recorded_track_rows

    detections = {
        int(message.frame_index): np.array(
            [
                (
                    d.center_x - d.width / 2,
                    d.center_y - d.height / 2,
                    d.center_x + d.width / 2,
                    d.center_y + d.height / 2,
                    d.score,
                )
                for d in message.detections
            ]
        ).reshape(-1, 5)
        for _, message, _ in iter_recorded(record, "gldt/detections")
    }
    arrays = [message for _, message, _ in iter_recorded(record, "gldt/tracks")]
    return bag, recorded_track_rows(record), completed.stdout, detections, arrays


def test_every_frame_is_answered(replay) -> None:
    bag, rows, stdout, _, _ = replay
    assert "0 frames without an answer" in stdout, stdout


def test_graph_detections_equal_offline_detections(replay) -> None:
    """Every frame's detections (after class filter and ROI merging) match, in GD and LD alike."""
    bag, _, _, graph, _ = replay
    _, _, offline = offline_run(bag)
    assert sorted(graph) == sorted(offline), "the graph detected on other frames than the offline run"
    if bag.name in MOTA_FLOOR:
        assert sum(len(d) for d in offline.values()) > 0, "no detections at all: nothing was compared"
    for index, expected in offline.items():
        got = graph[index]
        assert got.shape == expected.shape, (
            f"frame {index}: {len(got)} detections in the graph, {len(expected)} offline"
        )
        order_got, order_expected = np.lexsort(got.T[::-1]), np.lexsort(expected.T[::-1])
        np.testing.assert_allclose(got[order_got], expected[order_expected], atol=1e-4, err_msg=f"frame {index}")


def test_lockstep_replay_equals_offline_run(replay) -> None:
    bag, graph, _, _, _ = replay
    offline, _ = offline_rows(bag)
    if bag.name in MOTA_FLOOR:
        assert len(offline) > 0, "the offline run produced no tracks at all; nothing to compare"
    order_graph = np.lexsort((graph[:, 1], graph[:, 0]))
    order_offline = np.lexsort((offline[:, 1], offline[:, 0]))
    graph, offline = graph[order_graph], offline[order_offline]
    assert graph.shape == offline.shape, f"graph gave {len(graph)} track rows, offline {len(offline)}"
    np.testing.assert_array_equal(graph[:, :2], offline[:, :2], err_msg="frames/ids differ")
    np.testing.assert_allclose(graph[:, 2:6], offline[:, 2:6], atol=1e-4, rtol=0, err_msg="boxes differ")
    np.testing.assert_allclose(graph[:, 6], offline[:, 6], atol=1e-6, err_msg="scores differ")


def test_graph_tracks_meet_the_mota_floor(replay) -> None:
    from gldt_core.eval.mot_metrics import evaluate_sequence

    bag, graph, _, _, _ = replay
    if bag.name not in MOTA_FLOOR:
        return  # equivalence only, see MOTA_FLOOR
    _, ground_truth = offline_rows(bag)
    assert ground_truth is not None, f"{bag.name} has a MOTA floor but no ground truth"
    drones = ground_truth[ground_truth[:, 7] == 1]
    metrics = evaluate_sequence(drones, graph)
    assert metrics["MOTA"] >= MOTA_FLOOR[bag.name], f"{bag.name}: MOTA {metrics['MOTA']:.3f}"


def test_the_planner_stream_keeps_its_invariants(replay) -> None:
    """What a planner subscribed to /gldt/tracks relies on: one TrackArray per frame, every id in
    every frame from its first entry to its single REMOVED one, a class on every track that was
    matched, bearings from frame 0 on (the player sends camera_info first), and a time to collision
    whose validity seldom flips."""
    bag, _, _, _, arrays = replay
    from gldt_msgs.msg import Track

    frames = [int(array.frame_index) for array in arrays]
    assert frames == list(range(len(frames))), "not exactly one TrackArray per frame, in order"
    seen: dict[int, list[int]] = {}
    removed: set[int] = set()
    flips = track_frames = 0
    last_valid: dict[int, bool] = {}
    for array in arrays:
        for track in array.tracks:
            assert track.id not in removed, f"frame {array.frame_index}: id {track.id} published after REMOVED"
            seen.setdefault(track.id, []).append(int(array.frame_index))
            if track.state == Track.STATE_REMOVED:
                removed.add(track.id)
                continue
            assert track.state != Track.STATE_TENTATIVE
            assert track.bearing_valid, f"frame {array.frame_index}: track {track.id} has no bearing"
            assert abs(np.linalg.norm(track.line_of_sight) - 1.0) < 1e-9
            if track.hits > 0:
                assert track.class_id in (Track.CLASS_DRONE, Track.CLASS_BIRD, Track.CLASS_AIRPLANE)
            track_frames += 1
            valid = bool(track.time_to_collision_valid)
            flips += track.id in last_valid and last_valid[track.id] != valid
            last_valid[track.id] = valid
    for track_id, life in seen.items():
        assert life == list(range(life[0], life[0] + len(life))), f"id {track_id} has a hole: {life}"
    if bag.name in MOTA_FLOOR:
        assert track_frames > 0, "no tracks: nothing was checked"
    assert flips <= 0.1 * max(track_frames, 1), f"TTC validity flipped {flips} times in {track_frames} track-frames"


def test_a_namespaced_graph_serves_its_own_camera(tmp_path: Path) -> None:
    """`--namespace cam_a` moves camera input and outputs under /cam_a: one graph per camera."""
    from gldt_core.io.recording import iter_recorded, recorded_track_rows

    bag = REPO_ROOT / "bags" / "halmstad_v_drone_001"
    record = tmp_path / "cam_a.mcap"
    completed = subprocess.run(
        [str(PIPELINE), "--bag", str(bag), "--lockstep", "--namespace", "cam_a", "--record", str(record)],
        capture_output=True,
        text=True,
        timeout=600,
        env=isolated_ros_env(),
    )
    assert completed.returncode == 0, completed.stdout[-3000:] + completed.stderr[-3000:]
    assert "0 frames without an answer" in completed.stdout, completed.stdout[-3000:] + completed.stderr[-3000:]
    topics = {topic for topic, _, _ in iter_recorded(record, "")}
    assert "/cam_a/gldt/tracks" in topics and not any(t.startswith("/gldt") for t in topics), topics
    graph = recorded_track_rows(record)
    offline, _ = offline_rows(bag)
    assert graph.shape == offline.shape and len(graph) > 0
    np.testing.assert_array_equal(
        graph[np.lexsort((graph[:, 1], graph[:, 0]))][:, :2], offline[np.lexsort((offline[:, 1], offline[:, 0]))][:, :2]
    )
