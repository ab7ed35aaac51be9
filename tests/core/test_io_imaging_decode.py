"""Camera payload decoding: every supported encoding gives the same BGR frame; bad payloads fail clearly."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gldt_core.io.imaging import (
    ImageDecodeError,
    decode_compressed_image,
    decode_raw_image,
    encode_bgr8,
    validate_bgr_frame,
)

RNG = np.random.default_rng(3)
FRAME = RNG.integers(0, 256, size=(6, 7, 3), dtype=np.uint8)


@pytest.mark.parametrize(
    "encoding, payload",
    [
        ("bgr8", FRAME),
        ("rgb8", FRAME[:, :, ::-1]),
        ("bgra8", np.dstack([FRAME, np.full(FRAME.shape[:2], 255, np.uint8)])),
        ("rgba8", np.dstack([FRAME[:, :, ::-1], np.full(FRAME.shape[:2], 255, np.uint8)])),
    ],
)
def test_colour_encodings_decode_to_the_same_bgr(encoding: str, payload: np.ndarray) -> None:
    data = np.ascontiguousarray(payload).tobytes()
    decoded = decode_raw_image(data, FRAME.shape[1], FRAME.shape[0], encoding)
    np.testing.assert_array_equal(decoded, FRAME)


def test_mono8_becomes_three_equal_channels() -> None:
    gray = FRAME[:, :, 0].copy()
    decoded = decode_raw_image(gray.tobytes(), gray.shape[1], gray.shape[0], "mono8")
    assert decoded.shape == (*gray.shape, 3)
    for channel in range(3):
        np.testing.assert_array_equal(decoded[:, :, channel], gray)


def test_row_padding_in_step_is_skipped() -> None:
    padded = np.zeros((FRAME.shape[0], FRAME.shape[1] * 3 + 5), np.uint8)
    padded[:, : FRAME.shape[1] * 3] = FRAME.reshape(FRAME.shape[0], -1)
    decoded = decode_raw_image(padded.tobytes(), FRAME.shape[1], FRAME.shape[0], "bgr8", step=padded.shape[1])
    np.testing.assert_array_equal(decoded, FRAME)


def test_jpeg_and_png_compressed_images() -> None:
    ok, png = cv2.imencode(".png", FRAME)
    assert ok
    np.testing.assert_array_equal(decode_compressed_image(png.tobytes(), "png"), FRAME)
    smooth = np.full((32, 32, 3), 120, np.uint8)
    ok, jpeg = cv2.imencode(".jpg", smooth)
    assert np.abs(decode_compressed_image(jpeg.tobytes(), "jpeg").astype(int) - 120).max() <= 2


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"data": b"", "width": 0, "height": 0, "encoding": "bgr8"}, "empty image"),
        ({"data": b"\x00" * 10, "width": 4, "height": 4, "encoding": "bgr8"}, "needs 48"),
        ({"data": b"\x00" * 48, "width": 4, "height": 4, "encoding": "yuv422"}, "unsupported image encoding 'yuv422'"),
        ({"data": b"\x00" * 48, "width": 4, "height": 4, "encoding": "bgr8", "step": 5}, "step 5"),
    ],
)
def test_bad_raw_payloads_name_the_problem(kwargs: dict, message: str) -> None:
    with pytest.raises(ImageDecodeError, match=message):
        decode_raw_image(**kwargs)


def test_garbage_compressed_payload_is_refused() -> None:
    with pytest.raises(ImageDecodeError, match="cannot decode"):
        decode_compressed_image(b"not a jpeg at all", "jpeg")
    with pytest.raises(ImageDecodeError, match="empty"):
        decode_compressed_image(b"", "jpeg")


@settings(max_examples=60, deadline=None)
@given(
    width=st.integers(1, 40),
    height=st.integers(1, 40),
    encoding=st.sampled_from(["bgr8", "rgb8", "mono8", "bgra8", "mono16"]),
    extra=st.integers(-20, 20),
    data=st.data(),
)
def test_arbitrary_payloads_decode_or_raise_only_image_decode_error(width, height, encoding, extra, data) -> None:
    channels = {"bgr8": 3, "rgb8": 3, "mono8": 1, "bgra8": 4, "mono16": 2}[encoding]
    size = max(0, width * height * channels + extra)
    payload = data.draw(st.binary(min_size=size, max_size=size))
    try:
        frame = decode_raw_image(payload, width, height, encoding)
    except ImageDecodeError:
        assert extra < 0
        return
    assert frame.shape == (height, width, 3) and frame.dtype == np.uint8


def test_encode_bgr8_roundtrip_and_frame_validation() -> None:
    data, width, height, step = encode_bgr8(FRAME)
    np.testing.assert_array_equal(decode_raw_image(data, width, height, "bgr8", step), FRAME)
    with pytest.raises(ImageDecodeError, match="empty"):
        validate_bgr_frame(np.zeros((0, 5, 3), np.uint8))
    with pytest.raises(ImageDecodeError, match="uint8"):
        validate_bgr_frame(np.zeros((4, 5, 3), np.float32))
    assert validate_bgr_frame(np.zeros((4, 5), np.uint8)).shape == (4, 5, 3)
