"""rosbag2 MCAP bags: write, read back, convert, fail cleanly; the committed sample bags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from gldt_core.cli import main
from gldt_core.io.bag import (
    CAMERA_INFO_TOPIC,
    COMPRESSED_TOPIC,
    GROUND_TRUTH_TOPIC,
    IMAGE_TOPIC,
    BagSource,
    read_bag_frames,
    write_bag,
)
from gldt_core.io.sources import Frame, open_source
from gldt_core.sim import SceneRenderer, SceneSpec
from support import BAGS, HALMSTAD


def _frames(renderer: SceneRenderer) -> list[Frame]:
    return [Frame(k, k / renderer.fps, *renderer.render_with_truth(k)) for k in range(len(renderer))]


def _topics(bag: Path) -> set[str]:
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {t["topic_metadata"]["name"] for t in metadata["topics_with_message_count"]}


def test_raw_bag_round_trips_images_gt_stamps_and_camera_info(tmp_path: Path) -> None:
    renderer = SceneRenderer(SceneSpec(seed=9, frames=4, size=(160, 120), targets=3, birds=1))
    frames = _frames(renderer)
    summary = write_bag(
        tmp_path / "raw", frames, size=(160, 120), camera_matrix=renderer.camera_matrix(), compressed=False
    )
    assert summary.frames == 4 and not summary.compressed
    assert _topics(tmp_path / "raw") == {IMAGE_TOPIC, CAMERA_INFO_TOPIC, GROUND_TRUTH_TOPIC}
    source = BagSource(tmp_path / "raw")
    assert len(source) == 4 and source.size == (160, 120) and source.fps == pytest.approx(30.0)
    assert np.allclose(source.camera_matrix, renderer.camera_matrix())
    for original, loaded in zip(frames, read_bag_frames(tmp_path / "raw")):
        assert loaded.index == original.index
        assert loaded.stamp == pytest.approx(original.stamp, abs=1e-9)
        assert np.array_equal(loaded.image, original.image)
        assert np.allclose(loaded.ground_truth, original.ground_truth, atol=1e-6)


def test_compressed_bag_decodes_close_to_the_original(tmp_path: Path) -> None:
    renderer = SceneRenderer(SceneSpec(seed=2, frames=3, size=(320, 180), targets=2))
    frames = _frames(renderer)
    write_bag(tmp_path / "jpeg", frames, size=(320, 180), jpeg_quality=92)
    assert COMPRESSED_TOPIC in _topics(tmp_path / "jpeg")
    loaded = list(open_source(tmp_path / "jpeg"))
    assert len(loaded) == 3
    for original, frame in zip(frames, loaded):
        assert 0 < np.abs(frame.image.astype(int) - original.image).mean() < 8
        assert np.allclose(frame.ground_truth, original.ground_truth, atol=1e-6)
    mcap_files = list((tmp_path / "jpeg").glob("*.mcap"))
    assert len(mcap_files) == 1
    assert open_source(mcap_files[0]).size == (320, 180)


def test_failed_write_leaves_no_partial_bag(tmp_path: Path) -> None:
    renderer = SceneRenderer(SceneSpec(seed=1, frames=3, size=(64, 64), targets=1))

    def broken() -> object:
        yield Frame(0, 0.0, renderer.render(0))
        raise RuntimeError("source died")

    with pytest.raises(RuntimeError, match="source died"):
        write_bag(tmp_path / "bag", broken(), size=(64, 64))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="frame 0: image must be 64x64x3"):
        write_bag(tmp_path / "bag", [Frame(0, 0.0, np.zeros((10, 10, 3), np.uint8))], size=(64, 64))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="at least one frame"):
        write_bag(tmp_path / "bag", [], size=(64, 64))
    assert list(tmp_path.iterdir()) == []


def test_existing_bag_is_kept_unless_forced(tmp_path: Path) -> None:
    frames = _frames(SceneRenderer(SceneSpec(seed=1, frames=2, size=(64, 64), targets=1)))
    write_bag(tmp_path / "bag", frames, size=(64, 64))
    with pytest.raises(ValueError, match="already exists"):
        write_bag(tmp_path / "bag", frames[:1], size=(64, 64))
    assert len(BagSource(tmp_path / "bag")) == 2
    write_bag(tmp_path / "bag", frames[:1], size=(64, 64), overwrite=True)
    assert len(BagSource(tmp_path / "bag")) == 1


def test_gldt_bag_converts_a_mot_folder_with_a_frame_window(tmp_path: Path) -> None:
    from gldt_core.sim.writer import write_mot_sequence

    renderer = SceneRenderer(SceneSpec(seed=5, frames=8, size=(160, 90), targets=2))
    write_mot_sequence(renderer, tmp_path / "seq")
    assert (
        main(
            [
                "bag",
                "--from",
                str(tmp_path / "seq"),
                "--out",
                str(tmp_path / "bag"),
                "--start",
                "2",
                "--max-frames",
                "4",
            ]
        )
        == 0
    )
    frames = list(open_source(tmp_path / "bag"))
    assert [f.index for f in frames] == [0, 1, 2, 3]
    for frame in frames:
        expected = renderer.ground_truth(frame.index + 2)
        assert len(frame.ground_truth) == len(expected)
        if len(expected):
            assert np.allclose(frame.ground_truth[:, 2:6], expected[:, 2:6], atol=1e-6)
            assert np.all(frame.ground_truth[:, 0] == frame.index + 1)


def test_gldt_bag_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bag", "--from", str(tmp_path / "missing.mp4"), "--out", str(tmp_path / "b")]) == 2
    assert "source not found" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("name", ["synth_1080p_multi_uav", "halmstad_v_drone_001"])
def test_committed_sample_bags_are_small_and_readable(name: str) -> None:
    bag = BAGS / name
    assert (bag / "metadata.yaml").is_file(), f"sample bag {bag} missing (see bags/README.md)"
    size = sum(p.stat().st_size for p in bag.rglob("*") if p.is_file())
    assert size < 12e6
    source = open_source(bag)
    assert len(source) >= 60 and source.camera_matrix is not None
    first = next(iter(source))
    assert first.image.shape == (source.size[1], source.size[0], 3)
    assert len(source.ground_truth) > 0
    assert name in (BAGS / "README.md").read_text()


def test_synthetic_sample_bag_matches_its_regeneration_command() -> None:
    """bags/README.md says how the bag was made; the renderer must still produce it."""
    from gldt_core.sim import scene_ground_truth

    source = open_source(BAGS / "synth_1080p_multi_uav")
    assert source.size == (1920, 1080) and len(source) == 90
    expected = scene_ground_truth(seed=21, frames=90, size=(1920, 1080), targets=3, birds=2)
    loaded = source.ground_truth
    assert loaded.shape == expected.shape
    assert np.allclose(loaded[:, :8], expected[:, :8], atol=1e-6)
    assert np.allclose(loaded[:, 8], expected[:, 8], atol=1e-6)
    first = next(iter(source))
    rendered = SceneRenderer(SceneSpec(seed=21, frames=90, size=(1920, 1080), targets=3, birds=2)).render(0)
    assert np.abs(first.image.astype(int) - rendered).mean() < 4  # JPEG quality 80


HALMSTAD_GT = HALMSTAD / "gt" / "V_DRONE_001.txt"


@pytest.mark.skipif(not HALMSTAD_GT.is_file(), reason=f"Halmstad ground truth not present at {HALMSTAD_GT}")
def test_halmstad_sample_bag_carries_the_clip_ground_truth() -> None:
    from gldt_core.io.mot import read_mot

    expected = read_mot(HALMSTAD_GT)
    expected = expected[expected[:, 0] <= 150]
    loaded = open_source(BAGS / "halmstad_v_drone_001").ground_truth
    assert loaded.shape[0] == expected.shape[0]
    assert np.allclose(loaded[:, [0, 1, 2, 3, 4, 5, 7]], expected[:, [0, 1, 2, 3, 4, 5, 7]], atol=1e-6)
