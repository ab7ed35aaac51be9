"""Turn camera image payloads (ROS ``Image`` / ``CompressedImage`` fields) into BGR arrays.

Lives in the core, not in the ROS package, because bags are read without ROS and the nodes and
the offline runner must decode frames identically. Every failure raises
:class:`ImageDecodeError` (a ``ValueError``) whose message names the encoding and the size, so a
node can log one clear line and drop just that frame.
"""

from __future__ import annotations

import numpy as np

#: encoding -> (channels, dtype, conversion to BGR or None)
_RAW_ENCODINGS: dict[str, tuple[int, str]] = {
    "bgr8": (3, "uint8"),
    "rgb8": (3, "uint8"),
    "bgra8": (4, "uint8"),
    "rgba8": (4, "uint8"),
    "mono8": (1, "uint8"),
    "8UC1": (1, "uint8"),
    "8UC3": (3, "uint8"),
    "mono16": (1, "uint16"),
    "16UC1": (1, "uint16"),
}

SUPPORTED_ENCODINGS = tuple(_RAW_ENCODINGS)


class ImageDecodeError(ValueError):
    """An image payload that cannot be turned into a BGR frame."""


def decode_raw_image(
    data: bytes | bytearray | memoryview | np.ndarray,
    width: int,
    height: int,
    encoding: str,
    step: int | None = None,
    is_bigendian: bool = False,
) -> np.ndarray:
    """Decode a ``sensor_msgs/Image`` payload into an ``(H, W, 3)`` uint8 BGR array (a copy)."""
    if encoding not in _RAW_ENCODINGS:
        raise ImageDecodeError(f"unsupported image encoding {encoding!r}; supported: {', '.join(SUPPORTED_ENCODINGS)}")
    if width <= 0 or height <= 0:
        raise ImageDecodeError(f"empty image ({width}x{height}, encoding {encoding})")
    channels, dtype_name = _RAW_ENCODINGS[encoding]
    dtype = np.dtype(dtype_name).newbyteorder(">" if is_bigendian else "<")
    row_bytes = width * channels * dtype.itemsize
    step = int(step) if step else row_bytes
    if step < row_bytes:
        raise ImageDecodeError(
            f"image step {step} is smaller than one row ({width} px x {channels} ch x {dtype.itemsize} B) "
            f"for {width}x{height} {encoding}"
        )
    buffer = (
        np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8).reshape(-1)
    )
    if buffer.size < step * height:
        raise ImageDecodeError(
            f"image data has {buffer.size} bytes, {width}x{height} {encoding} with step {step} needs {step * height}"
        )
    rows = buffer[: step * height].reshape(height, step)[:, :row_bytes]
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels)
    if dtype.itemsize == 2:
        pixels = (pixels.astype(np.uint32) >> 8).astype(np.uint8)
    import cv2

    if encoding in ("bgr8", "8UC3"):
        return pixels.copy()
    if encoding == "rgb8":
        return cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    if encoding == "bgra8":
        return cv2.cvtColor(pixels, cv2.COLOR_BGRA2BGR)
    if encoding == "rgba8":
        return cv2.cvtColor(pixels, cv2.COLOR_RGBA2BGR)
    return cv2.cvtColor(pixels.reshape(height, width), cv2.COLOR_GRAY2BGR)


def decode_compressed_image(data: bytes | bytearray | memoryview | np.ndarray, fmt: str = "jpeg") -> np.ndarray:
    """Decode a ``sensor_msgs/CompressedImage`` payload (JPEG/PNG) into an ``(H, W, 3)`` BGR array."""
    import cv2

    buffer = (
        np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8).reshape(-1)
    )
    if buffer.size == 0:
        raise ImageDecodeError(f"empty compressed image (format {fmt!r})")
    image = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise ImageDecodeError(f"cannot decode compressed image of {buffer.size} bytes (format {fmt!r})")
    return image


def validate_bgr_frame(frame: np.ndarray, what: str = "frame") -> np.ndarray:
    """Check that ``frame`` is an ``(H, W, 3)`` uint8 array with H, W > 0; convert gray to BGR."""
    if not isinstance(frame, np.ndarray):
        raise ImageDecodeError(f"{what} must be a numpy array, got {type(frame).__name__}")
    if frame.ndim == 2:
        import cv2

        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ImageDecodeError(f"{what} must be HxWx3 BGR, got shape {frame.shape}")
    if frame.shape[0] == 0 or frame.shape[1] == 0:
        raise ImageDecodeError(f"{what} is empty (shape {frame.shape})")
    if frame.dtype != np.uint8:
        raise ImageDecodeError(f"{what} must be uint8, got {frame.dtype}")
    return frame


def encode_bgr8(frame: np.ndarray) -> tuple[bytes, int, int, int]:
    """Raw ``bgr8`` payload of a BGR frame: ``(data, width, height, step)``."""
    frame = np.ascontiguousarray(validate_bgr_frame(frame))
    height, width = frame.shape[:2]
    return frame.tobytes(), width, height, width * 3
