"""Copy-paste augmentation (``gldt_core.training.paste``): the matte, the cut, the paste and its wiring
into both training datasets and the training config."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gldt_core.training.paste import MARGIN, ObjectBank, ObjectPatch, cut_objects, paste_objects, soft_matte

SKY = (200, 170, 140)  # BGR


def _sky(h: int = 120, w: int = 160, seed: int = 0) -> np.ndarray:
    """A sky with a little sensor noise, so the ring's spread is not zero."""
    rng = np.random.default_rng(seed)
    image = np.empty((h, w, 3), np.uint8)
    image[:] = SKY
    return np.clip(image.astype(np.int16) + rng.integers(-3, 4, image.shape), 0, 255).astype(np.uint8)


def _frame_with_drone(x: int, y: int, side: int = 12, seed: int = 0, size: tuple[int, int] = (120, 160)) -> np.ndarray:
    frame = _sky(*size, seed=seed)
    cv2.rectangle(frame, (x, y), (x + side - 1, y + side - 1), (30, 30, 30), -1)
    return frame


def test_the_matte_is_opaque_on_the_object_and_clear_on_its_background() -> None:
    frame = _frame_with_drone(50, 40)
    patch = frame[40 - MARGIN : 52 + MARGIN, 50 - MARGIN : 62 + MARGIN]
    alpha = soft_matte(patch)
    inner = alpha[MARGIN + 2 : -MARGIN - 2, MARGIN + 2 : -MARGIN - 2]
    assert inner.min() > 0.95
    assert alpha[: MARGIN - 1].max() < 0.05 and alpha[:, : MARGIN - 1].max() < 0.05


def test_a_patch_of_plain_background_has_no_matte() -> None:
    assert soft_matte(_sky(24, 24)).max() < 0.05


def test_cut_keeps_the_exact_box_and_both_frames() -> None:
    previous, current = _frame_with_drone(48, 40), _frame_with_drone(50, 40)
    (patch,) = cut_objects(previous, current, np.array([[0, 50.3, 40.0, 61.7, 51.5]]))
    assert patch.class_index == 0
    assert patch.current.shape == patch.previous.shape == (12 + 2 * MARGIN, 12 + 2 * MARGIN, 3)
    assert patch.box == pytest.approx((MARGIN + 0.3, MARGIN, MARGIN + 11.7, MARGIN + 11.5))
    # The previous frame's drone sat 2 px to the left (frame x 48-59): its matte says so at the
    # patch column of frame x 61, where only the current drone is (two pixels from the old edge,
    # past the matte's one-pixel blur).
    columns = slice(61 - (50 - MARGIN), 62 - (50 - MARGIN))
    assert patch.current_matte[MARGIN + 2 : -MARGIN - 2, columns].min() > 0.5
    assert patch.previous_matte[MARGIN + 2 : -MARGIN - 2, columns].max() < 0.1


def test_cut_skips_objects_at_the_edge_tiny_ones_and_ones_that_do_not_stand_out() -> None:
    frame = _frame_with_drone(50, 40)
    boxes = np.array(
        [
            [0, 1.0, 1.0, 13.0, 13.0],  # its margin would leave the frame
            [1, 80.0, 80.0, 83.0, 83.0],  # under 4 px
            [2, 100.0, 20.0, 130.0, 50.0],  # plain sky: nothing to matte
            [0, 50.0, 40.0, 62.0, 52.0],  # the drone
        ]
    )
    patches = cut_objects(frame, frame, boxes)
    assert [p.class_index for p in patches] == [0]


def _bank(classes: tuple[int, ...] = (0, 1)) -> ObjectBank:
    patches = []
    for cls in classes:
        frame = _frame_with_drone(50, 40, seed=cls)
        patches += cut_objects(frame, frame, np.array([[cls, 50.0, 40.0, 62.0, 52.0]]))
    return ObjectBank(patches)


def test_paste_adds_labelled_boxes_that_hold_the_object_and_touch_nothing_else() -> None:
    image = _sky(192, 192, seed=5)
    existing = np.array([[0, 20.0, 20.0, 40.0, 40.0]], np.float32)
    (out,), boxes = paste_objects([image], existing, _bank(), np.random.default_rng(1), scale=1.0, count=3)
    assert len(boxes) == 4 and np.array_equal(boxes[0], existing[0])
    for cls, x1, y1, x2, y2 in boxes[1:]:
        assert cls in (0, 1)
        assert 0 <= x1 < x2 <= 192 and 0 <= y1 < y2 <= 192
        assert 12 * 0.8 - 0.01 <= x2 - x1 <= 12 * 1.25 + 0.01  # the object's own size, jittered
        assert out[int(y1) + 3 : int(y2) - 3, int(x1) + 3 : int(x2) - 3].mean() < 60  # the dark object is there
        assert not (x1 < 40 + 2 and x2 > 20 - 2 and y1 < 40 + 2 and y2 > 20 - 2)  # clear of the existing box
    changed = np.abs(out.astype(int) - image.astype(int)).max(axis=2) > 0
    inside = np.zeros_like(changed)
    for _, x1, y1, x2, y2 in boxes[1:]:
        inside[
            int(y1) - MARGIN - 2 : int(np.ceil(y2)) + MARGIN + 2, int(x1) - MARGIN - 2 : int(np.ceil(x2)) + MARGIN + 2
        ] = True
    assert changed.any() and not (changed & ~inside).any()


def test_paste_scales_objects_with_the_crop() -> None:
    (_,), boxes = paste_objects(
        [_sky(192, 192)], np.zeros((0, 5)), _bank((0,)), np.random.default_rng(2), scale=0.5, count=1
    )
    assert 12 * 0.5 * 0.8 - 0.01 <= boxes[0, 3] - boxes[0, 1] <= 12 * 0.5 * 1.25 + 0.01


def test_a_frame_pair_gets_the_object_at_the_same_place_in_both_frames() -> None:
    previous, current = _frame_with_drone(47, 40), _frame_with_drone(50, 40)
    bank = ObjectBank(cut_objects(previous, current, np.array([[0, 50.0, 40.0, 62.0, 52.0]])))
    (prev_out, cur_out), boxes = paste_objects(
        [_sky(96, 96, 3), _sky(96, 96, 4)], np.zeros((0, 5)), bank, np.random.default_rng(3), 1.0, 1
    )
    x1, y1, x2, y2 = boxes[0, 1:]
    band = slice(int(y1) + 2, int(y2) - 2)
    dark = lambda image: np.flatnonzero(image[band].mean(axis=(0, 2)) < 120)  # noqa: E731
    assert abs(dark(cur_out)[0] - x1) <= 1.5
    assert dark(prev_out)[0] < dark(cur_out)[0]  # the source's own motion is kept


def test_the_bank_caps_each_class_and_draws_classes_evenly() -> None:
    image, matte = np.zeros((9, 9, 3), np.uint8), np.ones((9, 9), np.float32)
    patch = lambda cls: ObjectPatch(cls, image, image, matte, matte, (4.0, 4.0, 5.0, 5.0))  # noqa: E731
    bank = ObjectBank([patch(0)] * 50 + [patch(1)] * 2)
    rng = np.random.default_rng(0)
    draws = [bank.draw(rng).class_index for _ in range(4000)]
    assert np.mean(draws) == pytest.approx(0.5, abs=0.03)  # not 2/52


def test_an_empty_bank_is_an_error_that_says_why() -> None:
    with pytest.raises(ValueError, match="at least one object patch"):
        ObjectBank([])


# --- wiring into the datasets and the config (needs the optional torch extra) ---------------


def _pairs(count: int = 6) -> list:
    from gldt_core.training.data import FramePair, _encode

    pairs = []
    for i in range(count):
        x = 300 + 10 * i
        previous = _frame_with_drone(x - 2, 250, side=20, seed=i, size=(512, 640))
        current = _frame_with_drone(x, 250, side=20, seed=i, size=(512, 640))
        box = np.array([[0, x, 250, x + 20, 270]], np.float32)
        pairs.append(FramePair(f"clip{i}", 2, _encode(previous), _encode(current), box))
    return pairs


@pytest.mark.parametrize("task", ["global", "local"])
def test_datasets_paste_when_asked_and_are_unchanged_when_not(task: str) -> None:
    pytest.importorskip("torch", reason="training is the optional `train` extra")
    from gldt_core.training.data import CopyPaste, GlobalPairDataset, LocalCropDataset

    pairs = _pairs()
    bank = ObjectBank.from_pairs(pairs, per_class=10)
    make = {
        "global": lambda cp: GlobalPairDataset(pairs, (192, 192), train=True, seed=0, copy_paste=cp),
        "local": lambda cp: LocalCropDataset(pairs, 160, 188, train=True, seed=0, negative_fraction=0.0, copy_paste=cp),
    }[task]
    plain, never, always = make(None), make(CopyPaste(bank, 0.0, 3)), make(CopyPaste(bank, 1.0, 3))
    extra = 0
    for index in range(len(pairs)):
        a, b, c = plain[index], never[index], always[index]
        assert all(np.array_equal(x.numpy(), y.numpy()) for x, y in zip(a, b))  # probability 0 is off
        extra += len(c[-1]) - len(a[-1])
        assert all(np.array_equal(x.numpy(), y.numpy()) for x, y in zip(c, always[index]))  # seeded
    assert extra >= len(pairs)  # every sample got at least one pasted object (few are clipped away)


def test_the_training_config_validates_copy_paste() -> None:
    pytest.importorskip("torch", reason="training is the optional `train` extra")
    from gldt_core.training.train import _copy_paste

    data = {"copy_paste": 1.5, "copy_paste_max": 3, "copy_paste_bank": 10}
    with pytest.raises(ValueError, match="data.copy_paste must be a probability"):
        _copy_paste(data, _pairs(2), 0)
    assert _copy_paste({**data, "copy_paste": 0.0}, _pairs(2), 0) is None
    with pytest.raises(ValueError, match="copy_paste_max"):
        _copy_paste({**data, "copy_paste": 0.5, "copy_paste_max": 0}, _pairs(2), 0)
    built = _copy_paste({**data, "copy_paste": 0.5}, _pairs(3), 0)
    assert built is not None and built.probability == 0.5 and len(built.bank) == 3
