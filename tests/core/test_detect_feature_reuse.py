"""AM-YOLO's split pair (``gldt export --feature-reuse``): the previous GD frame's backbone features
are reused instead of recomputed, with exactly the boxes of the full model, and a pair that does
not belong to its model is never used."""

from __future__ import annotations

import json
import shutil
from itertools import islice
from pathlib import Path

import numpy as np
import pytest

from gldt_core.detect import DetectorConfigError, GlobalCarry, GlobalDetector, shipped_model_path
from gldt_core.detect.feature_reuse import features_path, reuse_path
from support import REPO_ROOT


def stride4_channels(kind: str) -> int:
    """Channels of a shipped AM-YOLO's stride-4 stage (the features its split pair carries), from its card."""
    card = json.loads(shipped_model_path(kind).with_suffix(".json").read_text())
    return int(card["spec"]["channels"][1])


REAL_BAG = REPO_ROOT / "bags" / "halmstad_v_drone_001"
SYNTHETIC_BAG = REPO_ROOT / "bags" / "synth_1080p_multi_uav"


def bag_frames(bag: Path, count: int) -> list[np.ndarray]:
    from gldt_core.io.sources import open_source

    return [frame.image for frame in islice(open_source(str(bag)), count)]


def count_feature_runs(detector: GlobalDetector) -> list[int]:
    """Wrap the features model of ``detector`` so each run is counted (one list entry per run)."""
    reuse = detector.feature_reuse
    assert reuse is not None
    runs: list[int] = []
    original = reuse.features

    def counted(blob: np.ndarray) -> np.ndarray:
        runs.append(1)
        return original(blob)

    reuse.features = counted  # type: ignore[method-assign]
    return runs


@pytest.fixture(scope="module")
def detectors() -> tuple[GlobalDetector, GlobalDetector]:
    """The shipped AM-YOLO with its split pair and without, asked about every class at score 0
    (many boxes, so any numerical difference would show)."""
    reusing = GlobalDetector(num_threads=1, score_threshold=0.0, feature_reuse=True)
    full = GlobalDetector(num_threads=1, score_threshold=0.0, feature_reuse=False)
    assert reusing.feature_reuse is not None and full.feature_reuse is None
    return reusing, full


@pytest.mark.parametrize("bag", [REAL_BAG, SYNTHETIC_BAG], ids=["real-640x512", "synthetic-1080p"])
def test_a_gd_stretch_with_reused_features_gives_the_full_models_boxes(detectors, bag: Path) -> None:
    reusing, full = detectors
    frames = bag_frames(bag, 6)
    runs = count_feature_runs(reusing)
    carry_reusing = carry_full = None
    previous = None
    for frame in frames:
        boxes, carry_reusing = reusing.detect_pair(previous, frame, carry_reusing)
        expected, carry_full = full.detect_pair(previous, frame, carry_full)
        np.testing.assert_array_equal(boxes, expected)
        assert len(boxes) > 0
        previous = frame
    # Only the first frame had nothing to reuse; its previous frame is itself.
    assert len(runs) == 1
    assert carry_reusing is not None and carry_reusing.features is not None and carry_full.features is None


def test_features_of_another_frame_size_are_recomputed_not_fed(detectors) -> None:
    reusing, full = detectors
    frame = bag_frames(REAL_BAG, 1)[0]
    current_input, mapping = reusing.prepare(frame)
    wrong = np.zeros((1, 16, 8, 8), np.float32)
    boxes, features = reusing.detect_prepared(
        current_input, current_input, mapping, frame.shape[1], frame.shape[0], wrong
    )
    np.testing.assert_array_equal(boxes, full.detect(frame, frame))
    channels = stride4_channels("global")
    assert features is not None
    assert features.shape == (1, channels, current_input.shape[0] // 4, current_input.shape[1] // 4)
    # And a stale carry of another input size is ignored as a whole.
    stale = GlobalCarry(np.zeros((64, 64, 3), np.uint8), wrong)
    np.testing.assert_array_equal(reusing.detect_pair(frame, frame, stale)[0], full.detect(frame, frame))


def test_the_pipeline_reuses_features_within_gd_stretches_and_tracks_the_same(monkeypatch) -> None:
    """The real bag through GLDTSystem with and without reuse: the same tracks frame by frame;
    the features model runs once per GD stretch (its first frame), not once per GD frame."""
    from gldt_core.system import GLDTSystem
    from gldt_core.system.config import DetectorSettings, SystemConfig

    frames = bag_frames(REAL_BAG, 60)
    pipelines = {
        reuse: GLDTSystem(SystemConfig(detector=DetectorSettings(feature_reuse=reuse))) for reuse in (True, False)
    }
    runs = count_feature_runs(pipelines[True].global_detector)  # type: ignore[arg-type]
    stretches = 0
    was_global = False
    for index, frame in enumerate(frames):
        tracks = {reuse: pipeline.process(frame, index / 30.0) for reuse, pipeline in pipelines.items()}
        np.testing.assert_array_equal(tracks[True], tracks[False])
        is_global = pipelines[True].state.mode.name == "GLOBAL"
        stretches += is_global and not was_global
        was_global = is_global
    state = pipelines[True].state
    assert state.global_frames >= 30 and state.local_frames > 0  # the bag does reach LD
    assert len(runs) == stretches < state.global_frames


def _copy_model(tmp_path: Path) -> Path:
    source = shipped_model_path("global")
    for path in (source, source.with_suffix(".json"), features_path(source), reuse_path(source)):
        shutil.copy(path, tmp_path / path.name)
    return tmp_path / source.name


def test_missing_split_files_are_an_error_only_when_asked_for(tmp_path: Path) -> None:
    model = _copy_model(tmp_path)
    features_path(model).unlink()
    assert GlobalDetector(model, second_stage=None, num_threads=1).feature_reuse is None  # auto: the full model
    with pytest.raises(DetectorConfigError, match=r"global_amyolo\.features\.onnx not found.*--feature-reuse"):
        GlobalDetector(model, second_stage=None, num_threads=1, feature_reuse=True)


def test_a_split_pair_made_from_another_model_is_never_used(tmp_path: Path, caplog) -> None:
    model = _copy_model(tmp_path)
    frame = bag_frames(REAL_BAG, 1)[0]
    expected = GlobalDetector(model, second_stage=None, num_threads=1, feature_reuse=False).detect(frame, frame)
    # A re-exported model (here: the same graph with another producer string) has another hash.
    onnx = pytest.importorskip("onnx")
    proto = onnx.load(str(model))
    proto.producer_version = proto.producer_version + "-reexported"
    onnx.save(proto, str(model))
    with caplog.at_level("WARNING", logger="gldt.detect"):
        stale = GlobalDetector(model, second_stage=None, num_threads=1)
    assert stale.feature_reuse is None and "made from another version" in caplog.text
    np.testing.assert_array_equal(stale.detect(frame, frame), expected)
    with pytest.raises(DetectorConfigError, match="another version.*--feature-reuse"):
        GlobalDetector(model, second_stage=None, num_threads=1, feature_reuse=True)
    # A swapped reuse model is caught by its own hash.
    second = tmp_path / "second"
    second.mkdir()
    model = _copy_model(second)
    reuse_path(model).write_bytes(reuse_path(model).read_bytes() + b"\0")
    with pytest.raises(DetectorConfigError, match="is not the file"):
        GlobalDetector(model, second_stage=None, num_threads=1, feature_reuse=True)


def test_the_shipped_split_files_are_what_the_export_writes_today(tmp_path: Path) -> None:
    """Splitting the shipped AM-YOLOs again gives the shipped split files (none is stale): the same
    graphs and the same pairing metadata (model-level fields such as the onnx version that wrote
    them may differ between environments)."""
    onnx = pytest.importorskip("onnx")
    from gldt_core.export.feature_split import MAX_ABS_DIFF, write_feature_reuse

    for kind in ("global", "global_balanced"):
        source = shipped_model_path(kind)
        copy = tmp_path / source.name
        shutil.copy(source, copy)
        result = write_feature_reuse(copy)
        assert result.max_abs_diff <= MAX_ABS_DIFF and result.stride == 4
        assert result.channels == stride4_channels(kind)
        for made, shipped in ((result.features_model, features_path(source)), (result.reuse_model, reuse_path(source))):
            fresh, kept = onnx.load(str(made)), onnx.load(str(shipped))
            stale = f"{shipped.name} is stale: run `gldt export {source} --feature-reuse`"
            assert fresh.graph.SerializeToString() == kept.graph.SerializeToString(), stale
            assert {p.key: p.value for p in fresh.metadata_props} == {p.key: p.value for p in kept.metadata_props}, (
                stale
            )


def test_unreadable_split_files_fall_back_to_the_full_model_unless_required(tmp_path: Path, caplog) -> None:
    """A truncated copy or a Git LFS pointer in place of a split file must not stop the detector."""
    model = _copy_model(tmp_path)
    features_path(model).write_text("version https://git-lfs.github.com/spec/v1\noid sha256:0\nsize 1\n")
    with caplog.at_level("WARNING", logger="gldt.detect"):
        detector = GlobalDetector(model, second_stage=None, num_threads=1)
    assert detector.feature_reuse is None and "cannot use global_amyolo.features.onnx" in caplog.text
    frame = bag_frames(REAL_BAG, 1)[0]
    assert len(detector.detect(frame, frame)) > 0
    with pytest.raises(DetectorConfigError, match="cannot use global_amyolo.features.onnx"):
        GlobalDetector(model, second_stage=None, num_threads=1, feature_reuse=True)


def test_contract_errors_are_clear() -> None:
    with pytest.raises(DetectorConfigError, match="optimize_graph=False"):
        GlobalDetector(num_threads=1, optimize_graph=False, feature_reuse=True)
    detector = GlobalDetector(num_threads=1, optimize_graph=False)
    assert detector.feature_reuse is None  # geometry only: nothing is run, nothing to reuse
    frame = bag_frames(REAL_BAG, 1)[0]
    with pytest.raises(TypeError, match="GlobalCarry"):
        GlobalDetector(num_threads=1).detect_pair(frame, frame, np.zeros((384, 640, 3), np.uint8))  # type: ignore[arg-type]


def test_models_that_cannot_be_split_are_refused_with_nothing_written(tmp_path: Path) -> None:
    pytest.importorskip("onnx")
    from gldt_core.export.feature_split import FeatureSplitError, write_feature_reuse

    single = tmp_path / "global_nostff.onnx"
    shutil.copy(shipped_model_path("global_nostff"), single)
    with pytest.raises(FeatureSplitError, match="dual-frame"):
        write_feature_reuse(single)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["global_nostff.onnx"]


def test_export_cli_feature_reuse_arguments(tmp_path: Path, capsys) -> None:
    from gldt_core.cli import main

    model = str(shipped_model_path("global"))
    for arguments, message in (
        (["--feature-reuse", "--out", str(tmp_path / "x.onnx")], "drop --out"),
        (["--feature-reuse", "--rewrite-windows"], "separate steps"),
        (["--rewrite-windows"], "--out is required"),
    ):
        assert main(["export", model, *arguments]) == 2
        assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_model_written_over_gets_its_split_pair_refreshed(tmp_path: Path, capsys) -> None:
    """`gldt export` writing a model where a split pair lies (int8, a rewrite) splits the new file."""
    from gldt_core.cli.export import _refresh_or_drop_split_pair

    onnx = pytest.importorskip("onnx")
    model = _copy_model(tmp_path)
    proto = onnx.load(str(model))
    proto.producer_version = proto.producer_version + "-reexported"  # another file, the old pair stale
    onnx.save(proto, str(model))
    _refresh_or_drop_split_pair(model)
    assert "wrote global_amyolo.features.onnx" in capsys.readouterr().out
    assert GlobalDetector(model, second_stage=None, num_threads=1, feature_reuse=True).feature_reuse is not None
