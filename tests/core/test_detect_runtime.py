"""onnxruntime wrappers around the shipped models: contract, ROI batching/mapping and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gldt_core.detect import DetectorConfigError, GlobalDetector, LocalDetector, shipped_model_path
from gldt_core.detect.second_stage import GLOBAL_COLUMNS, LOCAL_COLUMNS
from gldt_core.paths import halmstad_root

HALMSTAD = halmstad_root()


def textured_frame(w: int, h: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    frame = np.clip(rng.normal(150, 12, size=(h, w, 3)), 0, 255).astype(np.uint8)
    frame[h // 3 : h // 3 + 12, w // 2 : w // 2 + 20] = 30  # a dark small object
    return frame


@pytest.fixture(scope="module")
def global_detector() -> GlobalDetector:
    return GlobalDetector(score_threshold=0.0, num_threads=1)


@pytest.fixture(scope="module")
def local_detector() -> LocalDetector:
    # The model alone: ROI batching and mapping are the detector's (the second stage caps
    # candidates over the whole batch; tests/core/test_detect_second_stage.py).
    return LocalDetector(score_threshold=0.0, num_threads=1, second_stage=None)


def test_shipped_models_exist_with_cards_and_fit_the_size_budget() -> None:
    for kind in ("global", "global_nostff", "local", "global_balanced", "local_balanced", "global_nostff_balanced"):
        path = shipped_model_path(kind)
        assert path.is_file() and path.stat().st_size <= 15 * 1024 * 1024
        card = json.loads(path.with_suffix(".json").read_text())
        assert card["opset"] >= 17 and card["class_ids"] == [1, 2, 3]
        expected_inputs = {
            "global": ["previous", "current"],
            "global_balanced": ["previous", "current"],
            "local": ["images"],
            "local_balanced": ["images"],
        }
        assert card["inputs"] == expected_inputs.get(kind, card["inputs"])
    for kind in ("global_balanced", "global_nostff_balanced"):
        assert (
            json.loads(shipped_model_path(kind).with_suffix(".json").read_text())["training_data"]["synthetic_share"]
            == 0.5
        )
    twin = json.loads(shipped_model_path("global_nostff_balanced").with_suffix(".json").read_text())["training_config"][
        "model"
    ]
    assert (
        twin["stff_levels"] == []
        and twin["channels"]
        == json.loads(shipped_model_path("global_balanced").with_suffix(".json").read_text())["training_config"][
            "model"
        ]["channels"]
    ), "the no-STFF twin differs from the balanced AM-YOLO only by STFF"


def test_global_detect_contract(global_detector: GlobalDetector) -> None:
    prev, cur = textured_frame(1920, 1080, 1), textured_frame(1920, 1080, 2)
    assert global_detector.input_size(1920, 1080) == (640, 384)
    dets = global_detector.detect(prev, cur)
    assert dets.dtype == np.float32 and dets.ndim == 2 and dets.shape[1] == GLOBAL_COLUMNS and len(dets) > 0
    assert (
        (dets[:, 0] >= 0).all()
        and (dets[:, 2] <= 1920).all()
        and (dets[:, 1] >= 0).all()
        and (dets[:, 3] <= 1080).all()
    )
    assert (dets[:, 2] >= dets[:, 0]).all() and (dets[:, 3] >= dets[:, 1]).all()
    assert set(np.unique(dets[:, 5]).tolist()) <= {1.0, 2.0, 3.0}
    assert (np.diff(dets[:, 4]) <= 0).all()  # sorted by score


def test_detectors_asked_about_some_classes_report_only_those() -> None:
    # Full-range noise: frames on which the global model names more than one class at score 0.
    rng = np.random.default_rng(0)
    prev, cur = (rng.integers(0, 256, size=(1080, 1920, 3)).astype(np.uint8) for _ in range(2))
    alone = {"score_threshold": 0.0, "num_threads": 1, "second_stage": None}
    every = GlobalDetector(**alone).detect(prev, cur)
    assert len(np.unique(every[:, 5])) > 1  # at score 0 the model names several classes here
    for classes in ((1,), (2, 3)):
        for second_stage in (None, "beside"):
            options = {**alone, "classes": classes, "second_stage": second_stage}
            asked = GlobalDetector(**options).detect(prev, cur)
            assert len(asked) and set(np.unique(asked[:, 5]).tolist()) <= set(map(float, classes))
    rois = np.array([[100, 100, 400, 400], [800, 300, 1100, 600]])
    local = LocalDetector(score_threshold=0.0, num_threads=1, classes=(1,)).detect_rois(cur, rois)
    assert len(local) and set(local[:, 5].tolist()) == {1.0}
    with pytest.raises(
        DetectorConfigError, match=r"classes \[4\] asked for, but the model outputs classes \[1, 2, 3\]"
    ):
        GlobalDetector(classes=(4,))
    with pytest.raises(DetectorConfigError, match="asked for"):
        LocalDetector(classes=())


def test_unoptimized_global_session_has_the_same_geometry_and_boxes(global_detector: GlobalDetector) -> None:
    """The frame buffer opens the model without graph optimisation (faster start): it must
    letterbox exactly as the detector does, and the model must mean the same."""
    geometry = GlobalDetector(score_threshold=0.0, num_threads=1, optimize_graph=False)
    for width, height in ((1920, 1080), (1280, 720), (333, 211)):
        assert geometry.input_size(width, height) == global_detector.input_size(width, height)
    rng = np.random.default_rng(5)
    feed = {name: rng.random((1, 3, 384, 640), dtype=np.float32) for name in global_detector.input_names}
    (raw_optimized,), (raw_plain,) = global_detector.session.run(None, feed), geometry.session.run(None, feed)
    np.testing.assert_allclose(raw_plain, raw_optimized, rtol=1e-3, atol=1e-3)


def test_global_accepts_grayscale_and_first_frame(global_detector: GlobalDetector) -> None:
    gray = textured_frame(640, 512)[..., 0]
    a = global_detector.detect(None, gray)
    b = global_detector.detect(np.dstack([gray] * 3), np.dstack([gray] * 3))
    assert np.allclose(a, b)
    with pytest.raises(ValueError, match="differ in size"):
        global_detector.detect(textured_frame(640, 480), textured_frame(640, 512))
    with pytest.raises(ValueError, match="uint8"):
        global_detector.detect(None, np.zeros((100, 100, 3), np.float64))


def test_odd_sized_frames_map_inside_the_frame(global_detector: GlobalDetector) -> None:
    frame = textured_frame(333, 211)
    dets = global_detector.detect(frame, frame)
    assert global_detector.input_size(333, 211)[0] % global_detector.multiple == 0
    assert (dets[:, 2] <= 333).all() and (dets[:, 3] <= 211).all()


def test_rois_map_back_to_full_frame(local_detector: LocalDetector) -> None:
    frame = textured_frame(800, 600)
    roi = np.array([[300, 150, 600, 450]])
    full = local_detector.detect_rois(frame, roi)
    alone = local_detector.detect_rois(np.ascontiguousarray(frame[150:450, 300:600]), np.array([[0, 0, 300, 300]]))
    assert full.shape[1] == LOCAL_COLUMNS and len(full) == len(alone) > 0
    assert np.allclose(full[:, :4] - [300, 150, 300, 150], alone[:, :4], atol=1e-3)
    assert np.allclose(full[:, 4:6], alone[:, 4:6])
    assert (full[:, 6] == 0).all()


def test_rois_run_as_one_batch_equal_to_single_calls(local_detector: LocalDetector) -> None:
    frame = textured_frame(1920, 1080)
    rois = np.array([[0, 0, 300, 300], [900, 300, 1200, 600], [1700, 900, 2000, 1200]])  # last one sticks out
    batched = local_detector.detect_rois(frame, rois)
    for index, roi in enumerate(rois):
        single = local_detector.detect_rois(frame, roi[None])
        part = batched[batched[:, 6] == index]
        assert len(part) == len(single)
        assert np.allclose(part[:, :6], single[:, :6], atol=1e-3)
    assert (batched[:, 2] <= 1920).all() and (batched[:, 3] <= 1080).all()
    assert local_detector.detect_rois(frame, np.zeros((0, 4))).shape == (0, LOCAL_COLUMNS)


def test_bad_rois_are_rejected(local_detector: LocalDetector) -> None:
    frame = textured_frame(640, 480)
    with pytest.raises(ValueError, match="\\(R, 4\\)"):
        local_detector.detect_rois(frame, np.array([1, 2, 3, 4]))
    with pytest.raises(ValueError, match="outside"):
        local_detector.detect_rois(frame, np.array([[700, 0, 1000, 300]]))
    with pytest.raises(ValueError, match="empty or inverted"):
        local_detector.detect_rois(frame, np.array([[10, 10, 10, 300]]))


def test_unusable_models_raise_config_errors(tmp_path: Path) -> None:
    missing = tmp_path / "nope.onnx"
    with pytest.raises(DetectorConfigError, match="nope.onnx.*not found"):
        GlobalDetector(missing)
    corrupt = tmp_path / "corrupt.onnx"
    corrupt.write_bytes(b"this is not a protobuf")
    with pytest.raises(DetectorConfigError, match="corrupt.onnx.*cannot load"):
        LocalDetector(corrupt)
    with pytest.raises(DetectorConfigError, match="local detector needs one"):
        LocalDetector(shipped_model_path("global"))
    with pytest.raises(DetectorConfigError, match="not available"):
        GlobalDetector(providers=("NoSuchExecutionProvider",))
    assert issubclass(DetectorConfigError, ValueError)


def test_detect_pair_reuses_the_previous_input_with_identical_boxes(global_detector: GlobalDetector) -> None:
    """A stream that hands back the carry (letterboxed input, features) gets exactly what detect() computes."""
    from gldt_core.detect import GlobalCarry

    frames = [textured_frame(960, 540, seed) for seed in range(3)]
    first, first_carry = global_detector.detect_pair(None, frames[0])
    np.testing.assert_array_equal(first, global_detector.detect(None, frames[0]))
    second, second_carry = global_detector.detect_pair(frames[0], frames[1], first_carry)
    np.testing.assert_array_equal(second, global_detector.detect(frames[0], frames[1]))
    # A carry of another size (the frame size changed) is ignored, not fed to the model.
    stale = global_detector.detect_pair(frames[1], frames[2], GlobalCarry(np.zeros((64, 64, 3), np.uint8)))[0]
    np.testing.assert_array_equal(stale, global_detector.detect(frames[1], frames[2]))
    assert second_carry.input.shape == first_carry.input.shape


def test_every_detector_session_stops_spinning_when_a_run_ends(
    global_detector: GlobalDetector, local_detector: LocalDetector
) -> None:
    """Several sessions share two cores (the split pair, GD and LD, the graph's processes): a
    session's idle threads must not busy-wait on the core the next one needs."""
    reuse = global_detector.feature_reuse
    assert reuse is not None  # the shipped AM-YOLO has its split pair
    sessions = [local_detector.session, global_detector.session, reuse.features_session, reuse.reuse_session]
    for session in sessions:
        assert session.get_session_options().get_session_config_entry("session.force_spinning_stop") == "1"
