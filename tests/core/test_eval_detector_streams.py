"""Real-detector streams: how they are made from a detector and cached (a tiny fake detector here)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gldt_core.eval import detector_streams
from gldt_core.eval.detector_streams import (
    DetectorStreamCache,
    cache_root,
    detect_frames,
    halmstad_drone_clips,
    shipped_detector_cache,
    stream_key,
)


class FakeDetector:
    """Finds one 'drone' at the frame's brightest column, plus a bird, a box nested in the drone
    and a NaN row that the system's steps drop; counts the frames it was run on."""

    def __init__(self) -> None:
        self.calls = 0
        self.pairs: list[tuple[int, int]] = []

    def detect(self, previous: np.ndarray, current: np.ndarray) -> np.ndarray:
        self.calls += 1
        self.pairs.append((int(previous[0, 0, 0]), int(current[0, 0, 0])))
        x = float(np.argmax(current[1, :, 0]))
        score = 0.1 + 0.01 * self.calls
        return np.array(
            [
                [x, 10.0, x + 20.0, 25.0, score, 1],  # drone
                [x + 2.0, 12.0, x + 10.0, 20.0, score / 2, 1],  # nested in it, lower score: dropped
                [50.0, 50.0, 60.0, 58.0, 0.9, 2],  # bird: not a tracked class
                [np.nan, 1.0, 5.0, 5.0, 0.5, 1],  # invalid: dropped
            ]
        )


def _frames(count: int) -> list[np.ndarray]:
    frames = []
    for k in range(count):
        image = np.zeros((40, 120, 3), dtype=np.uint8)
        image[0, 0, 0] = k  # the frame's number, for checking the pairs
        image[1, 3 * k + 5, 0] = 255  # the 'drone' moves 3 px per frame
        frames.append(image)
    return frames


def _cache(tmp_path: Path, model: Path, built: list[FakeDetector], threshold: float = 0.05) -> DetectorStreamCache:
    def make() -> FakeDetector:
        built.append(FakeDetector())
        return built[-1]

    key = stream_key([model], {"score_threshold": threshold})
    return DetectorStreamCache(key, make, root=tmp_path / "cache")


def test_detect_frames_runs_pairs_like_the_system_and_writes_mot_rows() -> None:
    detector = FakeDetector()
    rows, frames = detect_frames(detector, _frames(6), classes=(1,), nested_threshold=0.8)
    assert frames == 6 and detector.calls == 6
    # (previous, current) pairs, the first frame paired with itself.
    assert detector.pairs == [(0, 0), (0, 1), (1, 2), (2, 3), (3, 4), (4, 5)]
    assert rows.shape == (6, 10)  # only the drone: bird, nested box and NaN row dropped
    np.testing.assert_array_equal(rows[:, 0], np.arange(1, 7))
    np.testing.assert_allclose(rows[:, 2], 3 * np.arange(6) + 5)  # x of the top-left corner
    np.testing.assert_allclose(rows[:, 4:6], [[20.0, 15.0]] * 6)  # w, h
    assert np.all(rows[:, 1] == -1) and np.all(rows[:, 7:] == -1)
    rows, frames = detect_frames(FakeDetector(), _frames(6), max_frames=4)
    assert frames == 4 and rows[:, 0].max() == 4


def test_detect_frames_hands_the_carry_of_detect_pair_on() -> None:
    seen = []

    class PairDetector(FakeDetector):
        def detect_pair(self, previous, current, carry):
            seen.append(carry)
            return self.detect(previous, current), int(current[0, 0, 0])

    detect_frames(PairDetector(), _frames(4))
    assert seen == [None, 0, 1, 2]


def test_the_cache_is_reused_and_a_changed_model_is_recomputed(tmp_path: Path) -> None:
    model = tmp_path / "model.onnx"
    model.write_bytes(b"weights v1")
    built: list[FakeDetector] = []
    cache = _cache(tmp_path, model, built)
    first = cache.stream("clip_a", lambda: iter(_frames(8)), 30.0, (120, 40))
    assert not first.from_cache and len(built) == 1 and built[0].calls == 8
    assert (cache.directory / "clip_a.txt").is_file() and (cache.directory / "clip_a.json").is_file()

    # A new cache object for the same model: served from disk, no detector built.
    again_built: list[FakeDetector] = []
    again = _cache(tmp_path, model, again_built).stream("clip_a", lambda: iter(_frames(8)), 30.0, (120, 40))
    assert again.from_cache and again_built == []
    np.testing.assert_array_equal(again.rows, first.rows)
    assert (again.frames, again.fps, again.size) == (8, 30.0, (120, 40))

    # The model changes: another key, another folder, computed afresh.
    model.write_bytes(b"weights v2")
    changed_built: list[FakeDetector] = []
    changed = _cache(tmp_path, model, changed_built)
    assert changed.key != cache.key and changed.directory != cache.directory
    stream = changed.stream("clip_a", lambda: iter(_frames(8)), 30.0, (120, 40))
    assert not stream.from_cache and changed_built[0].calls == 8
    # So does another setting that shapes the rows.
    assert _cache(tmp_path, model, [], threshold=0.1).key != changed.key


def test_a_bounded_stream_serves_shorter_requests_and_is_recomputed_for_longer_ones(tmp_path: Path) -> None:
    model = tmp_path / "model.onnx"
    model.write_bytes(b"w")
    built: list[FakeDetector] = []
    cache = _cache(tmp_path, model, built)
    part = cache.stream("clip", lambda: iter(_frames(10)), 30.0, (120, 40), max_frames=5, total_frames=10)
    assert not part.from_cache and part.frames == 5 and built[0].calls == 5
    shorter = cache.stream("clip", lambda: iter(_frames(10)), 30.0, (120, 40), max_frames=3)
    assert shorter.from_cache and shorter.frames == 3 and shorter.rows[:, 0].max() == 3
    whole = cache.stream("clip", lambda: iter(_frames(10)), 30.0, (120, 40))
    assert not whole.from_cache and whole.frames == 10 and built[0].calls == 15
    bounded = cache.stream("clip", lambda: iter(_frames(10)), 30.0, (120, 40), max_frames=7)
    assert bounded.from_cache and bounded.frames == 7
    np.testing.assert_array_equal(bounded.rows, whole.rows[whole.rows[:, 0] <= 7])
    # A bound that covers the whole clip makes a complete stream.
    other = cache.stream("short", lambda: iter(_frames(4)), 30.0, (120, 40), max_frames=4, total_frames=4)
    assert not other.from_cache
    assert cache.stream("short", lambda: iter(_frames(4)), 30.0, (120, 40)).from_cache


def test_a_damaged_cache_entry_is_recomputed(tmp_path: Path) -> None:
    model = tmp_path / "model.onnx"
    model.write_bytes(b"w")
    built: list[FakeDetector] = []
    cache = _cache(tmp_path, model, built)
    cache.stream("clip", lambda: iter(_frames(6)), 30.0, (120, 40))
    rows_file = cache.directory / "clip.txt"
    rows_file.write_text(rows_file.read_text().splitlines()[0] + "\n")  # truncated
    stream = cache.stream("clip", lambda: iter(_frames(6)), 30.0, (120, 40))
    assert not stream.from_cache and len(stream.rows) == 6


def test_cache_root_follows_gldt_cache(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("GLDT_CACHE", str(tmp_path))
    assert cache_root() == tmp_path / "detector_streams"
    monkeypatch.delenv("GLDT_CACHE")
    assert cache_root() == Path("/tmp/gldt-cache/detector_streams")


def test_the_shipped_detector_key_covers_its_files_and_threshold_without_building_it(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import gldt_core.system.gldt_system as system

    def refuse(config):
        raise AssertionError("the detector must not be built to compute a key")

    monkeypatch.setattr(system, "build_detectors", refuse)
    low = shipped_detector_cache(score_threshold=0.05, root=tmp_path)
    high = shipped_detector_cache(score_threshold=0.1, root=tmp_path)
    assert low.key != high.key and low.directory.parent == tmp_path
    assert "second stage" in low.description
    from gldt_core.detect.shipped import DEFAULT_GLOBAL_MODEL

    names = {p.name for p in detector_streams.global_model_files(Path(DEFAULT_GLOBAL_MODEL), "beside")}
    assert {Path(DEFAULT_GLOBAL_MODEL).name, "second_stage.onnx"} <= names


def test_the_streams_are_am_yolos_boxes_alone_whatever_the_fusion_setting(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The tracking benchmark's real profiles are AM-YOLO's GD boxes (no tile fusion), the same
    stream (key and detector) whether or not the config fuses tiles."""
    import dataclasses

    import gldt_core.system.gldt_system as system
    from gldt_core.system.config import SystemConfig

    built: list[bool] = []
    monkeypatch.setattr(system, "build_detectors", lambda config: (built.append(config.detector.tile_fusion), None))
    fused = SystemConfig()
    alone = dataclasses.replace(fused, detector=dataclasses.replace(fused.detector, tile_fusion=False))
    assert fused.detector.tile_fusion
    caches = [shipped_detector_cache(config, root=tmp_path) for config in (fused, alone)]
    assert caches[0].key == caches[1].key
    caches[0]._make_detector()  # what a clip to compute would build
    assert built == [False]


def test_drone_clips_alternate_the_two_validation_splits(tmp_path: Path) -> None:
    (tmp_path / "videos").mkdir()
    (tmp_path / "gt").mkdir()
    for k in range(1, 11):
        for kind in ("V_DRONE", "V_BIRD"):
            (tmp_path / "videos" / f"{kind}_{k:03d}.mp4").write_bytes(b"")
            (tmp_path / "gt" / f"{kind}_{k:03d}.txt").write_text("")
    # Sorted position i goes to val when i % 5 == 2, to val_b when i % 5 == 4.
    assert halmstad_drone_clips(tmp_path) == [
        ("val", "V_DRONE_003"),
        ("val_b", "V_DRONE_005"),
        ("val", "V_DRONE_008"),
        ("val_b", "V_DRONE_010"),
    ]
    assert halmstad_drone_clips(tmp_path, 3) == halmstad_drone_clips(tmp_path)[:3]
