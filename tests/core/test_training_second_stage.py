"""Training the second stage: resumable to the same weights, calibration, box correction, and
refusals that overwrite nothing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from gldt_core.detect.second_stage import CROP_SIZE, SecondStage, encoded_iou
from gldt_core.training.crops import SOURCES, CropSet, label_boxes
from gldt_core.training.second_stage import (
    DEFAULTS,
    CropClassifier,
    ResumeError,
    calibrate,
    evaluate,
    expected_calibration_error,
    export_second_stage,
    fit_classifier,
    load_config,
    load_resume,
    model_signature,
    split_for_calibration,
)


def tiny_config(epochs: int = 3) -> dict:
    config = json.loads(json.dumps(DEFAULTS))
    config["model"] = {"channels": [4, 4, 8, 8], "hidden": 8}
    config["train"].update({"epochs": epochs, "batch_size": 16, "lr": 0.01})
    return config


def toy_crops(count: int = 64, seed: int = 0, margin: float = 1.0) -> CropSet:
    """Dark squares of class 1 (drone) and 2 (bird, smaller), background noise otherwise; an
    object is annotated ``margin`` times its square's side, centred on it."""
    rng = np.random.default_rng(seed)
    crops = rng.integers(140, 180, size=(count, 6, CROP_SIZE, CROP_SIZE)).astype(np.uint8)
    labels = rng.integers(0, 3, size=count)
    geometry = np.zeros((count, 4), np.float32)
    quality = np.zeros(count, np.float32)
    target = np.zeros((count, 4), np.float32)
    for i, label in enumerate(labels):
        # The candidate box is a third of the crop; a drone fills it half the time (IoU 1 or 0.25).
        geometry[i, 2:] = np.log(1 / 3)
        if label:
            half = 8 if label == 1 else 3
            crops[i, :, 32 - half : 32 + half, 32 - half : 32 + half] = 20
            target[i, 2:] = np.log(2 * half * margin / CROP_SIZE)
            geometry[i, 2:] = np.log(2 * half / CROP_SIZE) + (0.0 if rng.random() < 0.5 else np.log(2.0))
            quality[i] = encoded_iou(geometry[i : i + 1], target[i : i + 1])[0]
    return CropSet(
        crops=crops,
        labels=labels.astype(np.int64),
        geometry=geometry,
        quality=quality,
        target=target,
        scores=rng.uniform(0.01, 0.9, count).astype(np.float32),
        sources=np.full(count, SOURCES.index("global"), np.int8),
        clips=np.zeros(count, np.int32),
        clip_names=["V_DRONE_001"],
    )


def test_a_stopped_and_resumed_run_ends_with_the_same_weights(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    fit, calibration = toy_crops(), toy_crops(24, seed=1)
    straight = fit_classifier(tiny_config(), fit, calibration, tmp_path / "straight", progress=False)
    assert straight is not None
    stopped = tiny_config()
    stopped["train"]["max_wall_s"] = 0.0  # stops after the first epoch
    assert fit_classifier(stopped, fit, calibration, tmp_path / "resumed", progress=False) is None
    checkpoint = load_resume(tmp_path / "resumed" / "last.pt", tiny_config())
    assert checkpoint["epoch"] == 1
    resumed = fit_classifier(tiny_config(), fit, calibration, tmp_path / "resumed", checkpoint, progress=False)
    assert resumed is not None
    for (name, a), b in zip(straight[0].state_dict().items(), resumed[0].state_dict().values()):
        assert torch.equal(a, b), name
    assert resumed[1]["epochs"] == 3 and len(resumed[1]["log"]) == 3
    assert resumed[1]["cpu_seconds_total"] >= checkpoint["wall_s"]


def test_resume_refusals_are_one_line_and_touch_nothing(tmp_path: Path) -> None:
    with pytest.raises(ResumeError, match="checkpoint not found"):
        load_resume(tmp_path / "missing.pt", tiny_config())
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x80\x02 truncated")
    with pytest.raises(ResumeError, match="not a readable checkpoint") as error:
        load_resume(corrupt, tiny_config())
    assert "\n" not in str(error.value)
    short = tiny_config(1)
    short["train"]["batch_size"] = 4
    fit_classifier(short, toy_crops(48), toy_crops(8), tmp_path / "run", progress=False)
    good = tmp_path / "run" / "last.pt"
    before = good.read_bytes()
    other = json.loads(json.dumps(short))
    other["model"]["hidden"] = 16
    with pytest.raises(ResumeError, match="the config asks for"):
        load_resume(good, other)
    correcting = json.loads(json.dumps(short))
    correcting["model"]["box_correction"] = True
    with pytest.raises(ResumeError, match="the config asks for"):
        load_resume(good, correcting)
    longer = json.loads(json.dumps(short))
    longer["train"]["epochs"] = 5
    with pytest.raises(ResumeError, match="scheduled for"):
        fit_classifier(longer, toy_crops(48), toy_crops(8), tmp_path / "elsewhere", load_resume(good, longer))
    with pytest.raises(ValueError, match="the schedule needs at least"):
        fit_classifier(tiny_config(1), toy_crops(16), toy_crops(8), tmp_path / "elsewhere")
    assert good.read_bytes() == before and not (tmp_path / "elsewhere").exists()


def test_the_cli_refuses_a_bad_resume_before_building_anything(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from gldt_core.cli import main

    config = tmp_path / "c.yaml"
    config.write_text("train: {epochs: 1}\n")
    assert main(["train", "second-stage", "--config", str(config), "--resume", str(tmp_path / "no.pt")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "checkpoint not found" in err[0]
    with pytest.raises(ValueError, match="unknown config key"):
        bad = tmp_path / "bad.yaml"
        bad.write_text("train: {epoch: 1}\n")
        load_config(bad)


def test_calibration_lowers_the_calibration_error_and_exports_a_usable_model(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    fitted = fit_classifier(tiny_config(4), toy_crops(96), toy_crops(32, 1), tmp_path, progress=False)
    assert fitted is not None
    calibration_set = toy_crops(64, seed=2)
    entry = calibrate(fitted[0], calibration_set)
    assert entry["ece_after"] <= entry["ece_before"] + 1e-9
    path = export_second_stage(fitted[0], tmp_path / "second_stage.onnx", {"calibration": entry})
    stage = SecondStage(path, score_threshold=0.0)
    frame = np.full((128, 128, 3), 160, np.uint8)
    frame[56:72, 56:72] = 20
    rows = stage.rescore(frame, frame, np.array([[58.0, 58, 70, 70, 0.4, 1]]))
    assert rows.shape == (1, 9) and not stage.corrects_boxes
    np.testing.assert_allclose(rows[0, :4], [58, 58, 70, 70])  # without the correction head: the box stays


def test_the_correction_learns_the_annotations_margin_and_moves_the_boxes_at_run_time(tmp_path: Path) -> None:
    """Objects annotated at 1.5x their square: the corrected boxes overlap the annotations better
    than the candidates did, on crops the model never trained on, and in the exported model."""
    torch.set_num_threads(1)
    config = tiny_config(12)
    config["model"] = {"channels": [8, 8, 16, 16], "hidden": 32, "box_correction": True}
    fitted = fit_classifier(config, toy_crops(256, margin=1.5), toy_crops(32, 1, 1.5), tmp_path, progress=False)
    assert fitted is not None
    figures = evaluate(fitted[0], toy_crops(128, seed=3, margin=1.5))
    assert figures["drone_iou_mean_after"] > figures["drone_iou_mean_before"] + 0.1
    assert figures["drone_at_iou_0.5_after"] > figures["drone_at_iou_0.5_before"]
    path = export_second_stage(fitted[0], tmp_path / "second_stage.onnx", {"calibration": {"slope": 1.0, "bias": 0.0}})
    stage = SecondStage(path, score_threshold=0.0)
    assert stage.corrects_boxes
    frame = np.full((256, 256, 3), 160, np.uint8)
    frame[120:136, 120:136] = 20  # a 16 px drone, annotated 24 px
    rows = stage.rescore(frame, frame, np.array([[120.0, 120, 136, 136, 0.4, 1]]))
    sides = rows[0, 2:4] - rows[0, :2]
    assert np.all(sides > 17) and np.all(np.abs((rows[0, :2] + rows[0, 2:4]) / 2 - 128) < 3)


def test_decoding_inverts_encoding_and_the_encoded_iou_is_the_boxes_iou() -> None:
    from gldt_core.detect.second_stage import crop_windows, decode_boxes, encode_boxes
    from gldt_core.eval.detection_metrics import box_iou

    boxes = np.array([[10.0, 20, 30, 28], [100, 100, 164, 180], [5, 5, 6, 9]])
    others = boxes + np.array([[2.0, -1, 6, 0], [-10, 5, 0, 30], [0, 0, 3, 0]])
    windows = crop_windows(boxes)
    np.testing.assert_allclose(decode_boxes(encode_boxes(boxes, windows), windows), boxes, atol=1e-9)
    iou = encoded_iou(encode_boxes(boxes, windows), encode_boxes(others, windows))
    np.testing.assert_allclose(iou, np.diag(box_iou(boxes, others)), atol=1e-9)


def test_expected_calibration_error_of_a_perfect_and_a_wrong_forecast() -> None:
    outcome = np.array([0, 0, 1, 1], bool)
    assert expected_calibration_error(outcome.astype(float), outcome) == 0.0
    assert expected_calibration_error(1.0 - outcome, outcome) == pytest.approx(1.0)


def test_labels_come_from_the_object_a_candidate_sits_on() -> None:
    gt = np.array([[100.0, 100, 140, 130], [300, 300, 320, 320]])
    classes = np.array([1, 2])
    boxes = np.array(
        [
            [105.0, 105, 130, 125],  # on the drone: drone
            [302, 302, 318, 318],  # on the bird: bird
            [10, 10, 30, 30],  # nowhere: background
            [128, 118, 158, 148],  # grazing the drone: left out
        ]
    )
    labels, quality, matched = label_boxes(boxes, gt, classes)
    assert labels.tolist() == [1, 2, 0, -1] and matched.tolist() == [0, 1, -1, -1]
    assert quality[0] == pytest.approx(25 * 20 / (40 * 30))  # its IoU with the drone's box
    assert quality[1] == pytest.approx(16 * 16 / (20 * 20)) and quality[2] == 0.0


def test_calibration_clips_are_every_fifth_of_each_category() -> None:
    clips = [f"V_DRONE_{i:03d}" for i in range(10)] + [f"V_BIRD_{i:03d}" for i in range(5)]
    fit, calibration = split_for_calibration(clips, 5)
    assert calibration == ["V_BIRD_000", "V_DRONE_000", "V_DRONE_005"]
    assert sorted(fit + calibration) == sorted(clips)


def test_the_committed_checkpoint_resumes_under_the_shipped_config_and_matches_the_card() -> None:
    from gldt_core.detect.second_stage import classifier_path_for
    from gldt_core.detect.shipped import DEFAULT_GLOBAL_MODEL
    from gldt_core.paths import REPO_ROOT

    config = load_config(REPO_ROOT / "src/gldt_core/configs/train/second_stage.yaml")
    checkpoint = load_resume(REPO_ROOT / "checkpoints/second_stage.pt", config)
    assert checkpoint["epoch"] == config["train"]["epochs"]
    card = json.loads(classifier_path_for(DEFAULT_GLOBAL_MODEL).with_suffix(".json").read_text())
    assert card["training"]["cpu_seconds_total"] == pytest.approx(checkpoint["wall_s"], abs=0.1)
    assert (REPO_ROOT / "checkpoints/second_stage.pt").stat().st_size < 15 * 1024 * 1024


def test_synthetic_scenes_cycle_their_scales_and_refuse_a_bad_one() -> None:
    from gldt_core.sim import presets
    from gldt_core.training.second_stage import synthetic_scenes

    scenes = synthetic_scenes({"scenes": 3, "frames": 20, "scales": [0.5, 1.0]})
    assert [item.scale for item in scenes] == [0.5, 1.0, 0.5]
    assert [item.scene for item in scenes] == presets.split("train", count=3, frames=20)
    assert len({item.name for item in scenes}) == 3 and all("-x0.500" in scenes[i].name for i in (0, 2))
    assert synthetic_scenes({"scenes": 0, "frames": 20, "scales": []}) == []
    with pytest.raises(ValueError, match=r"data\.synthetic\.scales must be in \(0, 1\], got \[0\.5, 2\.0\]"):
        synthetic_scenes({"scenes": 1, "frames": 20, "scales": [0.5, 2.0]})


def test_a_synthetic_scene_is_cut_at_its_scale_with_its_drones_labelled(tmp_path: Path) -> None:
    from gldt_core.detect.shipped import DEFAULT_GLOBAL_MODEL, DEFAULT_LOCAL_MODEL
    from gldt_core.sim import SceneRenderer, presets
    from gldt_core.training.crops import CropSpec, SceneCrops, build_crops, scene_frames

    scene = presets.split("train", count=2, frames=11)[1]  # a MOT-FLY-like scene: drones of 12-80 px
    item = SceneCrops(scene, 1 / 3)
    frames = list(scene_frames(item, 5))
    assert len(frames) == 2  # frames 1 and 6, each with the frame before it
    previous, frame, boxes, classes = frames[0]
    assert frame.shape == previous.shape == (360, 640, 3)
    renderer = SceneRenderer(scene)
    _, rows = renderer.render_with_truth(1)
    np.testing.assert_allclose(boxes[:, :2], rows[:, 2:4] / 3, atol=1e-9)
    np.testing.assert_allclose(boxes[:, 2:] - boxes[:, :2], rows[:, 4:6] / 3, atol=1e-9)
    assert classes.tolist() == rows[:, 7].astype(int).tolist() and 1 in classes
    assert not np.array_equal(previous, frame)  # the pair shows motion

    spec = CropSpec(frame_step=5, local_candidates=0)
    crops = build_crops(
        tmp_path, [], spec, tmp_path / "cache", DEFAULT_GLOBAL_MODEL, DEFAULT_LOCAL_MODEL, False, scenes=[item]
    )
    assert crops.clip_names == [item.name]
    drones = crops.labels == 1
    assert drones.sum() >= 2 * len(rows[rows[:, 7] == 1])  # every drone jittered twice on each frame, at least
    assert (crops.quality[drones] > 0).all() and (crops.quality[crops.labels == 0] == 0).all()
    assert (
        tmp_path / "cache" / f"crops_{spec.key(DEFAULT_GLOBAL_MODEL, DEFAULT_LOCAL_MODEL)}" / f"{item.name}.npz"
    ).is_file()


@pytest.mark.parametrize("context", [2.0, 3.0])
def test_the_crops_cover_the_configured_context_around_each_box(context: float) -> None:
    from gldt_core.detect.global_detector import GlobalDetector
    from gldt_core.training.crops import CropSpec, cut_frames

    class NoCandidates(GlobalDetector):
        def __init__(self) -> None:  # no model: the jittered annotations alone are cut
            pass

        def detect(self, previous: np.ndarray | None, frame: np.ndarray) -> np.ndarray:
            return np.zeros((0, 9))

    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, size=(360, 640, 3), dtype=np.uint8)
    boxes = np.array([[100.0, 100.0, 160.0, 150.0], [400.0, 200.0, 460.0, 260.0]])
    spec = CropSpec(local_candidates=0, random_boxes=0, jitter_copies=4, context=context)
    cut = cut_frames([(frame, frame, boxes, np.array([1, 2]))], "V_DRONE_001", spec, NoCandidates(), None)
    assert (cut["labels"] > 0).all() and len(cut["labels"]) >= 4
    longer = np.exp(cut["geometry"][:, 2:].max(axis=1))  # the box's longer side over the crop's
    np.testing.assert_allclose(longer, 1 / context, rtol=1e-5)
    with pytest.raises(ValueError, match=r"data\.crops\.context must be > 0 .*got 0"):
        CropSpec(context=0)


def test_another_context_cuts_crops_into_a_cache_of_their_own(tmp_path: Path) -> None:
    from gldt_core.training.crops import CropSpec

    model = tmp_path / "m.onnx"
    model.write_bytes(b"model")
    assert CropSpec().key(model, model) != CropSpec(context=2.0).key(model, model)
    config = load_config(Path(__file__).parents[2] / "src/gldt_core/configs/train/second_stage_context2.yaml")
    assert config["data"]["crops"]["context"] == 2.0


def test_the_focal_class_loss_is_weighted_cross_entropy_at_gamma_0_and_spares_easy_crops_above() -> None:
    from gldt_core.training.second_stage import class_loss

    torch.manual_seed(0)
    logits = torch.randn(32, 4) * 3
    labels = torch.randint(0, 4, (32,))
    weights = torch.tensor([0.5, 1.0, 2.0, 3.0])
    plain = torch.nn.functional.cross_entropy(logits, labels, weight=weights)
    assert torch.equal(class_loss(logits, labels, weights, 0.0), plain)
    # Written out per crop: w_y * (1 - p_y)^gamma * -log p_y, over the sum of the w_y.
    p = torch.softmax(logits, dim=1)[torch.arange(32), labels]
    w = weights[labels]
    expected = (w * (1 - p) ** 2 * -torch.log(p)).sum() / w.sum()
    torch.testing.assert_close(class_loss(logits, labels, weights, 2.0), expected)
    # A crop classified right with p = 0.99 loses 10^4 of its term; a confident mistake keeps nearly all of it.
    easy = torch.tensor([[0.0, 0.0, 0.0, 0.0]])
    easy[0, 1] = float(np.log(0.99 / 0.01 * 3))
    one = torch.tensor([1])
    ratio = class_loss(easy, one, weights, 2.0) / class_loss(easy, one, weights, 0.0)
    assert ratio.item() == pytest.approx(1e-4, rel=1e-3)
    wrong = torch.tensor([[0.0, -5.0, 0.0, 0.0]])
    assert (class_loss(wrong, one, weights, 2.0) / class_loss(wrong, one, weights, 0.0)).item() > 0.99


def test_a_negative_focal_gamma_is_refused_in_one_line(tmp_path: Path) -> None:
    config = tiny_config()
    config["train"]["focal_gamma"] = -1
    with pytest.raises(ValueError, match=r"^train\.focal_gamma must be >= 0, got -1$"):
        fit_classifier(config, toy_crops(), toy_crops(seed=1), tmp_path)
    config["train"]["focal_gamma"] = "two"
    with pytest.raises(ValueError, match=r"^train\.focal_gamma must be >= 0, got 'two'$"):
        fit_classifier(config, toy_crops(), toy_crops(seed=1), tmp_path)
    assert not any(tmp_path.iterdir()), "nothing written"
    torch.set_num_threads(1)
    config["train"]["focal_gamma"] = 2.0
    config["train"]["epochs"] = 8
    fitted = fit_classifier(config, toy_crops(96), toy_crops(32, 1), tmp_path, progress=False)
    assert fitted is not None and evaluate(fitted[0], toy_crops(64, seed=2))["accuracy"] >= 0.9
    focal = load_config(Path(__file__).parents[2] / "src/gldt_core/configs/train/second_stage_focal.yaml")
    assert focal["train"]["focal_gamma"] == 2.0


def test_colour_augmentation_off_draws_as_before_and_on_changes_colour_only() -> None:
    from gldt_core.training.second_stage import augment

    rng = np.random.default_rng(0)
    crops = rng.integers(0, 256, size=(16, 6, 8, 8)).astype(np.uint8)
    geometry, target = rng.normal(size=(16, 4)), rng.normal(size=(16, 4))
    plain = augment(crops, geometry, target, np.random.default_rng(1))
    off = augment(crops, geometry, target, np.random.default_rng(1), (0.0, 0.0))
    assert all(np.array_equal(a, b) for a, b in zip(plain, off, strict=True))
    grey, grey_geometry, grey_target = augment(crops, geometry, target, np.random.default_rng(1), (0.0, 1.0))
    # Every crop grey: the three channels of each frame equal, the two frames still apart; the
    # flips (and so the boxes) are the plain run's.
    for frame in (slice(0, 3), slice(3, 6)):
        channels = grey[:, frame]
        assert np.array_equal(channels[:, 0], channels[:, 1]) and np.array_equal(channels[:, 0], channels[:, 2])
    assert not np.array_equal(grey[:, 0], grey[:, 3])
    assert np.array_equal(grey_geometry, plain[1]) and np.array_equal(grey_target, plain[2])
    # Grey is the BT.601 luma of the flipped crop, before the shared brightness/contrast jitter:
    # a crop that is already grey stays what the plain run makes of it.
    flat = np.repeat(crops[:, [0, 3]], 3, axis=1)  # each frame grey already: (B, B, B, B', B', B')
    np.testing.assert_allclose(
        augment(flat, geometry, target, np.random.default_rng(1), (0.0, 1.0))[0],
        augment(flat, geometry, target, np.random.default_rng(1))[0],
        atol=1e-3,
    )
    # Channel gains move each channel by its own factor, the same in both frames.
    tinted = augment(
        np.full((4, 6, 2, 2), 100, np.uint8), geometry[:4], target[:4], np.random.default_rng(3), (0.2, 0.0)
    )[0]
    per_channel = tinted[:, :, 0, 0]
    assert np.array_equal(per_channel[:, :3], per_channel[:, 3:])
    assert (np.ptp(per_channel[:, :3], axis=1) > 0).all()


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("colour_jitter", -0.1, r"^train\.colour_jitter must be in \[0, 1\), got -0\.1$"),
        ("colour_jitter", 1.0, r"^train\.colour_jitter must be in \[0, 1\), got 1\.0$"),
        ("grayscale_p", 1.5, r"^train\.grayscale_p must be in \[0, 1\], got 1\.5$"),
        ("grayscale_p", "a fifth", r"^train\.grayscale_p must be in \[0, 1\], got 'a fifth'$"),
    ],
)
def test_a_bad_colour_augmentation_is_refused_in_one_line(tmp_path: Path, key: str, value: float, message: str) -> None:
    config = tiny_config()
    config["train"][key] = value
    with pytest.raises(ValueError, match=message):
        fit_classifier(config, toy_crops(), toy_crops(seed=1), tmp_path)
    assert not any(tmp_path.iterdir()), "nothing written"
    colour = load_config(Path(__file__).parents[2] / "src/gldt_core/configs/train/second_stage_colour.yaml")
    assert (colour["train"]["colour_jitter"], colour["train"]["grayscale_p"]) == (0.2, 0.2)


def test_border_input_norm_sees_the_crop_against_its_sky_in_torch_and_in_onnx(tmp_path: Path) -> None:
    import onnxruntime as ort

    torch.manual_seed(0)
    crops = toy_crops(8)
    geometry = torch.from_numpy(crops.geometry)
    plain = torch.from_numpy(crops.crops.astype(np.float32))
    # Another day's sky: every channel of both frames shifted by its own offset, nothing clipped.
    tinted = plain + torch.tensor([30.0, -20.0, 10.0, 30.0, -20.0, 10.0]).reshape(1, 6, 1, 1)
    assert 0 <= float(tinted.min()) and float(tinted.max()) <= 255
    border = CropClassifier([4, 4, 8, 8], 8, input_norm="border").eval()
    raw = CropClassifier([4, 4, 8, 8], 8).eval()
    with torch.no_grad():  # weights large enough that an untrained model's logits follow its input
        for parameter in (*border.parameters(), *raw.parameters()):
            parameter.normal_(0.0, 0.5)
    with torch.no_grad():
        np.testing.assert_allclose(border(tinted, geometry)[0], border(plain, geometry)[0], atol=1e-4)
        assert float((raw(tinted, geometry)[0] - raw(plain, geometry)[0]).abs().max()) > 1e-3
        # The object still counts: a darker square is another input.
        darker = plain.clone()
        darker[:, :, 28:36, 28:36] -= 15
        assert float((border(darker, geometry)[0] - border(plain, geometry)[0]).abs().max()) > 1e-3
    path = export_second_stage(border, tmp_path / "second_stage.onnx", {})
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = [session.run(["class_logits"], {"crops": c.numpy(), "geometry": crops.geometry})[0] for c in (plain, tinted)]
    np.testing.assert_allclose(got[1], got[0], atol=1e-4)
    # A border model's checkpoint is not resumed or exported under a config without the option.
    config = json.loads(json.dumps(DEFAULTS))
    bordered = json.loads(json.dumps(DEFAULTS))
    bordered["model"]["input_norm"] = "border"
    assert model_signature(bordered) != model_signature(config)
    assert "input_norm" not in model_signature(config)["model"]  # the shipped checkpoint's signature
    shipped_configs = Path(__file__).parents[2] / "src/gldt_core/configs/train"
    assert load_config(shipped_configs / "second_stage_border.yaml")["model"]["input_norm"] == "border"


def test_an_unknown_input_norm_is_refused_in_one_line(tmp_path: Path) -> None:
    config = tiny_config()
    config["model"]["input_norm"] = "sky"
    with pytest.raises(ValueError, match=r"^model\.input_norm must be one of none, border, got 'sky'$"):
        fit_classifier(config, toy_crops(), toy_crops(seed=1), tmp_path)
    assert not any(tmp_path.iterdir()), "nothing written"


def ensemble_config(tmp_path: Path, epochs: int = 4) -> Path:
    """An ensemble of two tiny members, one seeing its crops against their border ring."""
    (tmp_path / "member.yaml").write_text(
        f"model: {{channels: [4, 4, 8, 8], hidden: 8}}\ntrain: {{epochs: {epochs}, batch_size: 16, lr: 0.01}}\n"
    )
    path = tmp_path / "ensemble.yaml"
    path.write_text(
        f"out_dir: {tmp_path / 'run'}\n"
        "members:\n  - config: member.yaml\n  - config: member.yaml\n    model: {input_norm: border}\n"
        "    train: {grayscale_p: 0.2}\n"
    )
    return path


def test_an_ensemble_averages_its_members_log_probabilities_and_exports_as_one_model(tmp_path: Path) -> None:
    from gldt_core.training.second_stage import CropClassifierEnsemble

    torch.set_num_threads(1)
    members = []
    for norm in ("none", "border"):
        config = tiny_config(2)
        config["model"]["input_norm"] = norm
        fitted = fit_classifier(config, toy_crops(96), toy_crops(16, 1), tmp_path / norm, progress=False)
        assert fitted is not None
        members.append(fitted[0].eval())
    ensemble = CropClassifierEnsemble(members).eval()
    crops, geometry = torch.rand(5, 6, CROP_SIZE, CROP_SIZE) * 255, torch.randn(5, 4) * 0.3
    with torch.no_grad():
        log_p, quality, correction = ensemble.outputs(crops, geometry)
        alone = [member(crops, geometry) for member in members]
    mean = (torch.log_softmax(alone[0][0], 1) + torch.log_softmax(alone[1][0], 1)) / 2
    torch.testing.assert_close(log_p, mean)
    torch.testing.assert_close(quality, (alone[0][1] + alone[1][1]) / 2)
    assert correction is None
    assert not torch.allclose(torch.log_softmax(alone[0][0], 1), torch.log_softmax(alone[1][0], 1))
    entry = calibrate(ensemble, toy_crops(64, seed=2))
    path = export_second_stage(ensemble, tmp_path / "second_stage.onnx", {"calibration": entry})
    stage = SecondStage(path, score_threshold=0.0)
    logits, stage_quality, _ = stage.classify(crops.numpy(), geometry.numpy())
    np.testing.assert_allclose(logits, mean.numpy(), atol=1e-4)
    np.testing.assert_allclose(stage_quality, quality.numpy().reshape(-1), atol=1e-4)
    with pytest.raises(ValueError, match="at least two members"):
        CropClassifierEnsemble(members[:1])
    correcting = CropClassifier([4, 4, 8, 8], 8, box_correction=True)
    with pytest.raises(ValueError, match="cannot correct boxes"):
        CropClassifierEnsemble([members[0], correcting])


def test_an_ensemble_config_gives_each_member_its_changes_and_refuses_bad_ones_in_one_line(tmp_path: Path) -> None:
    config = load_config(ensemble_config(tmp_path))
    first, second = config["members"]
    assert config["out_dir"] == str(tmp_path / "run")
    assert (first["model"]["input_norm"], second["model"]["input_norm"]) == ("none", "border")
    assert (first["train"]["grayscale_p"], second["train"]["grayscale_p"]) == (0.0, 0.2)
    assert first["model"]["channels"] == second["model"]["channels"] == [4, 4, 8, 8]
    committed = load_config(Path(__file__).parents[2] / "src/gldt_core/configs/train/second_stage_ensemble.yaml")
    assert [member["model"]["input_norm"] for member in committed["members"]] == ["none", "border"]
    assert [member["train"]["grayscale_p"] for member in committed["members"]] == [0.0, 0.2]
    cases = {
        "members:\n  - config: member.yaml\n": "at least two member configs",
        "members: [{config: member.yaml}, {config: member.yaml}]\nseed: 3\n": "only members and out_dir, not seed",
        "members: [{config: member.yaml}, member.yaml]\n": r"members\[1\] must be a mapping with config",
        "members: [{config: member.yaml}, {config: member.yaml, model: {box_correction: true}}]\n": "corrects boxes",
        "members: [{config: member.yaml}, {config: member.yaml, data: {calibration_period: 3}}]\n": "data section",
        "members: [{config: member.yaml}, {config: member.yaml, train: {epoch: 3}}]\n": "unknown config key",
        "members: [{config: member.yaml}, {config: ensemble.yaml}]\n": "is an ensemble itself",
        "members: [{config: member.yaml}, {config: missing.yaml}]\n": "config not found",
    }
    for text, message in cases.items():
        bad = tmp_path / "bad.yaml"
        bad.write_text(text)
        with pytest.raises((ValueError, FileNotFoundError), match=message) as error:
            load_config(bad)
        assert "\n" not in str(error.value)


def test_an_ensemble_trains_each_member_and_a_resume_reads_finished_members_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gldt_core.training import second_stage

    torch.set_num_threads(1)
    about = {"crop_spec": {"context": 3.0}, "fit_clips": ["V_DRONE_001"], "calibration_clips": ["V_DRONE_002"]}
    monkeypatch.setattr(
        second_stage, "training_crops", lambda config, progress=True: (toy_crops(96), toy_crops(64, 2), about)
    )
    config = load_config(ensemble_config(tmp_path))
    out = tmp_path / "run"
    with pytest.raises(ResumeError, match="not an ensemble's run directory"):
        second_stage.train_second_stage(config, resume=out, progress=False)
    assert not out.exists()
    path = second_stage.train_second_stage(config, progress=False)
    assert path == out / "second_stage.onnx"
    card = json.loads(path.with_suffix(".json").read_text())
    assert [len(member["log"]) for member in card["training"]["members"]] == [4, 4]
    assert card["training"]["epochs"] == 4 and card["calibration"]["slope"] > 0
    before = {name: (out / name / "last.pt").read_bytes() for name in ("member_0", "member_1")}
    frame = np.full((128, 128, 3), 160, np.uint8)
    frame[56:72, 56:72] = 20
    candidates = np.array([[58.0, 58, 70, 70, 0.4, 1], [10, 10, 30, 30, 0.3, 1]])
    rows = SecondStage(path, score_threshold=0.0).rescore(frame, frame, candidates)
    again = second_stage.train_second_stage(config, resume=out, progress=False)  # both members finished
    assert {name: (out / name / "last.pt").read_bytes() for name in before} == before
    np.testing.assert_allclose(SecondStage(again, score_threshold=0.0).rescore(frame, frame, candidates), rows)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ResumeError, match="holds no member_N/last.pt"):
        second_stage.train_second_stage(config, resume=empty, progress=False)


def test_the_distillation_loss_mixes_cross_entropy_with_the_kl_from_the_teacher_and_iou_with_its_quality() -> None:
    from gldt_core.training.second_stage import losses

    torch.manual_seed(0)
    logits, quality = torch.randn(6, 4), torch.randn(6, 1)
    labels, iou = torch.tensor([0, 1, 2, 3, 1, 1]), torch.rand(6)
    batch = (labels, torch.zeros(6, 4), torch.zeros(6, 4), iou)
    weights = torch.ones(4)
    teacher_probabilities = torch.softmax(torch.randn(6, 4), dim=1)
    teacher_iou = torch.rand(6)
    plain_ce, plain_bce, _ = losses((logits, quality, None), batch, weights, (1.0, 1.0))
    for weight, temperature in ((0.5, 2.0), (1.0, 1.0), (0.25, 4.0)):
        ce, bce, _ = losses(
            (logits, quality, None),
            batch,
            weights,
            (1.0, 1.0),
            teacher=(torch.log(teacher_probabilities), teacher_iou),
            distill=(weight, temperature),
        )
        student = torch.softmax(logits / temperature, dim=1)
        kl = (teacher_probabilities * (torch.log(teacher_probabilities) - torch.log(student))).sum(dim=1).mean()
        torch.testing.assert_close(ce, (1 - weight) * plain_ce + weight * temperature**2 * kl)
        target = (1 - weight) * iou + weight * teacher_iou
        torch.testing.assert_close(
            bce, torch.nn.functional.binary_cross_entropy_with_logits(quality.reshape(-1), target)
        )
    # A student that already answers as its teacher at temperature 1 has nothing left to learn from it.
    itself = (torch.log_softmax(logits, 1), iou)
    ce, _, _ = losses((logits, quality, None), batch, weights, (1.0, 1.0), teacher=itself, distill=(1.0, 1.0))
    assert float(ce) == pytest.approx(0.0, abs=1e-6)


def clipped_crops(count: int = 128, seed: int = 0) -> CropSet:
    """Toy crops spread over four clips of two categories, so that they fall into two folds."""
    crops = toy_crops(count, seed)
    crops.clips = np.arange(count, dtype=np.int32) % 4
    crops.clip_names = ["V_DRONE_001", "V_BIRD_001", "V_DRONE_002", "V_BIRD_002"]
    return crops


def teacher_config_file(tmp_path: Path, text: str = "") -> Path:
    """A tiny second-stage config (``text`` appended) for a student to learn from."""
    path = tmp_path / "teacher.yaml"
    path.write_text(
        f"model: {{channels: [4, 4, 8, 8], hidden: 8}}\ntrain: {{epochs: 4, batch_size: 16, lr: 0.01}}\n{text}"
    )
    return path


def distilled_config(teacher: Path | None, weight: float, epochs: int = 4) -> dict:
    config = tiny_config(epochs)
    config["train"].update(
        {"teacher": None if teacher is None else str(teacher), "distill_weight": weight, "distill_temperature": 2.0}
    )
    return config


def test_clips_are_dealt_into_folds_by_category() -> None:
    from gldt_core.training.second_stage import clip_folds

    crops = clipped_crops(12)
    crops.clip_names = ["V_DRONE_003", "V_BIRD_001", "V_DRONE_001", "V_BIRD_002"]
    folds = clip_folds(crops, 2)
    by_clip = {crops.clip_names[c]: int(f) for c, f in zip(crops.clips, folds)}
    assert by_clip == {"V_DRONE_001": 0, "V_DRONE_003": 1, "V_BIRD_001": 0, "V_BIRD_002": 1}
    # Only the clips with crops in the set are dealt: a fit set's clip_names also name the
    # calibration clips (every fifth), which would otherwise all fall into one fold.
    fit = toy_crops(32)
    fit.clip_names = [f"V_DRONE_{i:03d}" for i in range(20)]
    fit.clips = np.repeat([c for c in range(20) if c % 5], 2).astype(np.int32)  # 16 clips, 2 crops each
    assert np.bincount(clip_folds(fit, 5), minlength=5).tolist() == [8, 6, 6, 6, 6]


def test_each_fold_is_answered_by_a_teacher_trained_on_the_other_folds_only(tmp_path: Path) -> None:
    from gldt_core.training.second_stage import clip_folds, out_of_fold_answers, teacher_answers, teacher_members

    torch.set_num_threads(1)
    fit, calibration = clipped_crops(), toy_crops(16, 1)
    config = distilled_config(teacher_config_file(tmp_path), 0.5)
    members = teacher_members(config)
    answers = out_of_fold_answers(members, 2, 2.0, fit, calibration, tmp_path / "run", progress=False)
    assert answers is not None and answers[2] > 0
    folds = clip_folds(fit, 2)
    teacher = load_config(config["train"]["teacher"])
    for k in (0, 1):
        alone = fit_classifier(teacher, fit.subset(folds != k), calibration, tmp_path / f"alone_{k}", progress=False)
        assert alone is not None
        expected = teacher_answers(alone[0], fit.subset(folds == k), 2.0)
        np.testing.assert_allclose(answers[0][folds == k], expected[0], atol=1e-6)
        np.testing.assert_allclose(answers[1][folds == k], expected[1], atol=1e-6)
    assert (tmp_path / "run" / "teacher_fold_1" / "member_0" / "last.pt").is_file()
    before = (tmp_path / "run" / "teacher_fold_0" / "member_0" / "last.pt").read_bytes()
    again = out_of_fold_answers(members, 2, 2.0, fit, calibration, tmp_path / "run", progress=False)  # read back
    assert again is not None and np.array_equal(again[0], answers[0])
    assert (tmp_path / "run" / "teacher_fold_0" / "member_0" / "last.pt").read_bytes() == before


def test_a_student_at_full_distillation_weight_learns_its_teachers_answers_not_the_labels(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gldt_core.training import second_stage
    from gldt_core.training.second_stage import predict

    torch.set_num_threads(1)
    fit, held_out = clipped_crops(), toy_crops(64, seed=5)
    says_bird = np.log(np.full((len(fit.labels), 4), 0.01, np.float32))
    says_bird[:, 2] = np.log(0.97)
    monkeypatch.setattr(second_stage, "out_of_fold_answers", lambda *args, **kwargs: (says_bird, fit.quality, 7.0))
    config = distilled_config(teacher_config_file(tmp_path), 1.0, epochs=6)
    taught = fit_classifier(config, fit, toy_crops(16, 1), tmp_path / "taught", progress=False)
    plain = fit_classifier(tiny_config(6), fit, toy_crops(16, 1), tmp_path / "plain", progress=False)
    assert taught is not None and plain is not None
    assert (predict(taught[0], held_out)[0].argmax(axis=1) == 2).mean() > 0.9
    assert (predict(plain[0], held_out)[0].argmax(axis=1) == held_out.labels).mean() > 0.8
    assert taught[1]["teacher"] == {"config": config["train"]["teacher"], "folds": 2, "cpu_seconds_total": 7.0}


def test_bad_distillation_settings_and_teachers_are_refused_in_one_line_before_anything_is_written(
    tmp_path: Path,
) -> None:
    from gldt_core.training.second_stage import check_member

    good = teacher_config_file(tmp_path)
    (tmp_path / "other_crops.yaml").write_text(good.read_text() + "data: {calibration_period: 3}\n")
    (tmp_path / "correcting.yaml").write_text(good.read_text() + "model: {box_correction: true}\n")
    (tmp_path / "taught.yaml").write_text(
        good.read_text().replace("lr: 0.01}", f"lr: 0.01, teacher: {good}, distill_weight: 0.5}}")
    )
    correcting_student = distilled_config(good, 0.5)
    correcting_student["model"]["box_correction"] = True
    one_fold = distilled_config(good, 0.5)
    one_fold["train"]["teacher_folds"] = 1
    cold = distilled_config(good, 0.5)
    cold["train"]["distill_temperature"] = 0
    cases = [
        (distilled_config(tmp_path / "missing.yaml", 0.5), "config not found"),
        (distilled_config(tmp_path / "other_crops.yaml", 0.5), "cuts other crops"),
        (distilled_config(tmp_path / "correcting.yaml", 0.5), "corrects boxes"),
        (distilled_config(tmp_path / "taught.yaml", 0.5), "learns from a teacher itself"),
        (distilled_config(good, 0.0), "go together"),
        (distilled_config(None, 0.5), "go together"),
        (distilled_config(good, 1.5), r"distill_weight must be in \[0, 1\]"),
        (correcting_student, "cannot learn from a teacher"),
        (one_fold, "teacher_folds must be an integer >= 2"),
        (cold, "distill_temperature must be > 0"),
    ]
    for config, message in cases:
        with pytest.raises((ValueError, FileNotFoundError), match=message) as error:
            check_member(config)
        assert "\n" not in str(error.value)
        with pytest.raises((ValueError, FileNotFoundError), match=message):
            fit_classifier(config, clipped_crops(48), toy_crops(8), tmp_path / "never", progress=False)
    assert not (tmp_path / "never").exists()
    student = tmp_path / "student.yaml"
    student.write_text("train: {teacher: teacher.yaml, distill_weight: 0.5}\n")
    assert load_config(student)["train"]["teacher"] == str(good)  # relative to the student's file
    committed = load_config(Path(__file__).parents[2] / "src/gldt_core/configs/train/second_stage_distilled.yaml")
    check_member(committed)


def test_a_distilled_run_resumes_only_under_the_teacher_it_started_with(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    fit, calibration = clipped_crops(), toy_crops(24, seed=1)
    config = distilled_config(teacher_config_file(tmp_path), 0.5, 3)
    straight = fit_classifier(config, fit, calibration, tmp_path / "straight", progress=False)
    stopped = distilled_config(teacher_config_file(tmp_path), 0.5, 3)
    stopped["train"]["max_wall_s"] = 0.0  # the student's: it stops after its first epoch
    assert fit_classifier(stopped, fit, calibration, tmp_path / "resumed", progress=False) is None
    checkpoint = load_resume(tmp_path / "resumed" / "last.pt", stopped)
    before = (tmp_path / "resumed" / "last.pt").read_bytes()
    other = tmp_path / "other"
    other.mkdir()
    other_teacher = distilled_config(teacher_config_file(other, "seed: 5\n"), 0.5, 3)
    with pytest.raises(ResumeError, match="learnt from another teacher") as error:
        fit_classifier(other_teacher, fit, calibration, tmp_path / "resumed", checkpoint)
    assert "\n" not in str(error.value) and (tmp_path / "resumed" / "last.pt").read_bytes() == before
    resumed = fit_classifier(config, fit, calibration, tmp_path / "resumed", checkpoint, progress=False)
    assert straight is not None and resumed is not None
    for (name, a), b in zip(straight[0].state_dict().items(), resumed[0].state_dict().values()):
        assert torch.equal(a, b), name
