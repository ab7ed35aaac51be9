"""Fault injection on recorded data: damaged MCAP files, wrong message types, odd images.

A sense-and-avoid stack that crashes on a bad frame is worse than none, and a reader that
silently drops frames corrupts every metric computed from the recording. The contract checked
here (issue 9) for a damaged bag read through :func:`gldt_core.io.sources.open_source`:

* either every frame before the damage is yielded and then a ``ValueError`` naming the file is
  raised, or the damaged part is skipped with one warning naming the file;
* never another exception type (a traceback instead of one line), never a silent loss.

The MCAP walk that finds the damage is :func:`gldt_core.io.mcap_file.read_mcap`; how frames,
ground truth and errors follow from it is :class:`gldt_core.io.bag.BagSource`.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gldt_core.io.bag import CAMERA_INFO_TOPIC, COMPRESSED_TOPIC, IMAGE_TOPIC, default_camera_matrix
from gldt_core.io.bag import _camera_info as camera_info_message  # the writer's own CameraInfo layout
from gldt_core.io.sources import Frame, open_source
from support import SYNTH_BAG

SAMPLE = SYNTH_BAG
SAMPLE_MCAP = SAMPLE / "synth_1080p_multi_uav.mcap"
FPS = 30.0


# --------------------------------------------------------------------------- helpers
def _store() -> Any:
    from gldt_core.io.ros_types import typestore

    return typestore()


def _damaged_copy(tmp_path: Path, payload: bytes, name: str = "damaged") -> Path:
    """The sample bag folder with its MCAP replaced by ``payload`` (metadata unchanged)."""
    folder = tmp_path / name
    folder.mkdir()
    shutil.copy(SAMPLE / "metadata.yaml", folder / "metadata.yaml")
    (folder / SAMPLE_MCAP.name).write_bytes(payload)
    return folder


def _chunks() -> list[tuple[int, int, int]]:
    """``(start_offset, end_offset, first_message_ns)`` of every chunk of the intact sample bag,
    read with the ``mcap`` library (independent of the reader under test)."""
    from mcap.reader import make_reader

    with SAMPLE_MCAP.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.chunk_indexes, "sample bag has no chunk index"
    return sorted(
        (c.chunk_start_offset, c.chunk_start_offset + c.chunk_length, c.message_start_time)
        for c in summary.chunk_indexes
    )


def _frames_before(offset: int) -> int:
    """Frames whose messages all lie in chunks that end before byte ``offset``."""
    damaged = [first_ns for start, end, first_ns in _chunks() if end > offset]
    if not damaged:
        return 90
    limit_ns = min(damaged)
    return sum(1 for k in range(90) if round(k * 1e9 / FPS) < limit_ns)


def _read_all(folder: Path) -> tuple[list[Frame], BaseException | None]:
    """Frames yielded before the first exception (opening included), and that exception."""
    frames: list[Frame] = []
    try:
        for frame in open_source(folder):
            frames.append(frame)
    except Exception as error:  # noqa: BLE001 - the test classifies whatever comes out
        return frames, error
    return frames, None


def _assert_damage_contract(
    folder: Path, expect_before: int, caplog: pytest.LogCaptureFixture, total: int = 90
) -> None:
    """The documented outcome for a damaged bag (module docstring)."""
    with caplog.at_level(logging.WARNING):
        frames, error = _read_all(folder)
    indices = [f.index for f in frames]
    assert indices[:expect_before] == list(range(expect_before)), (
        f"frames before the damage were lost: got indices {indices[: expect_before + 3]}..."
    )
    stamps = [f.stamp for f in frames]
    assert stamps == sorted(stamps)
    if error is not None:
        assert isinstance(error, ValueError), f"{type(error).__module__}.{type(error).__name__}: {error}"
        assert folder.name in str(error), f"error does not name the file: {error}"
        assert "\n" not in str(error).strip()
    elif len(frames) < total:
        warned = [r for r in caplog.records if r.levelno >= logging.WARNING and folder.name in r.getMessage()]
        assert warned, f"{total - len(frames)} frames silently dropped (no error, no warning naming the file)"


def _header(store: Any, seconds: float) -> Any:
    ns = int(round(seconds * 1e9))
    stamp = store.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")


def _write_bag(
    folder: Path,
    topic: str,
    msgtype: str,
    messages: list[Any],
    *,
    camera_matrix: np.ndarray | None = None,
    info_size: tuple[int, int] = (64, 48),
    with_camera_info: bool = True,
) -> Path:
    """A small MCAP bag with ``messages`` on ``topic`` (any type) and a CameraInfo per frame."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _store()
    k = default_camera_matrix(info_size) if camera_matrix is None else camera_matrix
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        image_conn = writer.add_connection(topic, msgtype, typestore=store)
        info_conn = (
            writer.add_connection(CAMERA_INFO_TOPIC, "sensor_msgs/msg/CameraInfo", typestore=store)
            if with_camera_info
            else None
        )
        for index, message in enumerate(messages):
            stamp = index / FPS
            ns = int(round(stamp * 1e9))
            writer.write(image_conn, ns, store.serialize_cdr(message, msgtype))
            if info_conn is not None:
                info = camera_info_message(store, _header(store, stamp), info_size, k)
                writer.write(info_conn, ns, store.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
    return folder


def _raw_image(store: Any, index: int, image: np.ndarray, encoding: str) -> Any:
    """A ``sensor_msgs/Image`` of a BGR test image in ``encoding`` (converted here with numpy)."""
    if encoding == "bgr8":
        pixels = image
    elif encoding == "rgb8":
        pixels = image[:, :, ::-1]
    elif encoding == "mono8":
        pixels = image[:, :, :1]
    else:
        raise AssertionError(encoding)
    pixels = np.ascontiguousarray(pixels)
    height, width, channels = pixels.shape
    return store.types["sensor_msgs/msg/Image"](
        header=_header(store, index / FPS),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels,
        data=pixels.reshape(-1),
    )


def _raw(store: Any, index: int, width: int, height: int, data: np.ndarray | None = None) -> Any:
    payload = np.full(width * height * 3, 77, np.uint8) if data is None else data
    return store.types["sensor_msgs/msg/Image"](
        header=_header(store, index / FPS),
        height=height,
        width=width,
        encoding="bgr8",
        is_bigendian=0,
        step=width * 3,
        data=payload,
    )


def _test_image(width: int = 64, height: int = 48, gray: bool = False) -> np.ndarray:
    """Smooth colour gradients (distinct B, G, R so a channel swap shows; smooth so JPEG keeps them)."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    image = np.stack([40 + 180 * x / width, 30 + 200 * y / height, 220 - 100 * (x + y) / (width + height)], axis=2)
    image = image.round().astype(np.uint8)
    if gray:
        image = np.repeat(image[:, :, :1], 3, axis=2)
    return np.ascontiguousarray(image)


# --------------------------------------------------------------------------- the intact bag
def test_intact_sample_bag_has_chunks_to_damage() -> None:
    """The damage tests need a bag of several chunks (reading it whole is test_bag_roundtrip's job)."""
    chunks = _chunks()
    assert len(chunks) >= 3
    assert _frames_before(chunks[1][1]) > 0 and _frames_before(chunks[-1][0]) < 90
    assert len(open_source(SAMPLE)) == 90


# --------------------------------------------------------------------------- truncation
@pytest.mark.parametrize("where", ["inside_header", "third_chunk", "last_bytes"])
def test_truncated_mcap_keeps_frames_before_the_cut_and_names_the_file(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, where: str
) -> None:
    data = SAMPLE_MCAP.read_bytes()
    chunks = _chunks()
    offset = {
        "inside_header": 100,
        "third_chunk": chunks[2][0] + 1000,
        "last_bytes": len(data) - 10,
    }[where]
    folder = _damaged_copy(tmp_path, data[:offset], f"trunc_{where}")
    _assert_damage_contract(folder, _frames_before(offset), caplog)


@pytest.mark.parametrize(
    "relative, length", [(49, 64), (50, 8), (89, 200)], ids=["first_record", "record_length", "message_payload_header"]
)
def test_garbage_over_a_chunk_never_loses_frames_silently(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, relative: int, length: int
) -> None:
    """Garbage bytes over the record framing of the third chunk (offsets from the chunk start:
    49 is where its first record begins for an uncompressed chunk)."""
    data = bytearray(SAMPLE_MCAP.read_bytes())
    start = _chunks()[2][0]
    data[start + relative : start + relative + length] = (
        np.random.default_rng(1).integers(0, 256, length, dtype=np.uint8).tobytes()
    )
    folder = _damaged_copy(tmp_path, bytes(data), f"garbage_{relative}")
    _assert_damage_contract(folder, _frames_before(start + 1), caplog)


def test_cli_on_a_truncated_bag_fails_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gldt_core.cli import main

    data = SAMPLE_MCAP.read_bytes()
    folder = _damaged_copy(tmp_path, data[: len(data) // 2], "cut_bag")
    code = main(["bag", "--from", str(folder), "--out", str(tmp_path / "copy")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "cut_bag" in err
    assert not (tmp_path / "copy").exists()


# --------------------------------------------------------------------------- message types
def test_wrong_message_type_on_the_image_topic_is_a_clear_value_error(tmp_path: Path) -> None:
    store = _store()
    messages = [store.types["std_msgs/msg/String"](data="not an image") for _ in range(3)]
    folder = _write_bag(tmp_path / "wrong_type", IMAGE_TOPIC, "std_msgs/msg/String", messages)
    frames, error = _read_all(folder)
    assert frames == []
    assert isinstance(error, ValueError), f"{type(error).__name__}: {error}"
    text = str(error)
    assert "std_msgs/msg/String" in text and IMAGE_TOPIC in text and "wrong_type" in text


def test_bag_with_only_an_image_topic_is_readable(tmp_path: Path) -> None:
    store = _store()
    image = _test_image()
    folder = _write_bag(
        tmp_path / "image_only",
        IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        [_raw_image(store, k, image, "bgr8") for k in range(3)],
        with_camera_info=False,
    )
    frames, error = _read_all(folder)
    assert error is None, f"{type(error).__name__}: {error}"
    assert len(frames) == 3 and all(np.array_equal(f.image, image) for f in frames)


# --------------------------------------------------------------------------- encodings and sizes
def test_bgr8_rgb8_mono8_and_jpeg_give_the_same_frame(tmp_path: Path) -> None:
    import cv2

    store = _store()
    colour, gray = _test_image(), _test_image(gray=True)
    decoded: dict[str, list[np.ndarray]] = {}
    for encoding in ("bgr8", "rgb8", "mono8"):
        folder = _write_bag(
            tmp_path / encoding,
            IMAGE_TOPIC,
            "sensor_msgs/msg/Image",
            [_raw_image(store, 0, colour, encoding), _raw_image(store, 1, gray, encoding)],
        )
        decoded[encoding] = [f.image for f in open_source(folder)]
    jpeg = []
    for k, image in enumerate((colour, gray)):
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 98])
        assert ok
        jpeg.append(
            store.types["sensor_msgs/msg/CompressedImage"](
                header=_header(store, k / FPS), format="jpeg", data=data.reshape(-1)
            )
        )
    folder = _write_bag(tmp_path / "jpeg", COMPRESSED_TOPIC, "sensor_msgs/msg/CompressedImage", jpeg)
    decoded["jpeg"] = [f.image for f in open_source(folder)]

    assert np.array_equal(decoded["bgr8"][0], colour)
    assert np.array_equal(decoded["rgb8"][0], colour)
    for encoding in ("bgr8", "rgb8", "mono8"):
        assert decoded[encoding][1].shape == (48, 64, 3)
        assert np.array_equal(decoded[encoding][1], gray), encoding
    assert np.abs(decoded["jpeg"][0].astype(int) - colour).mean() < 4
    assert np.abs(decoded["jpeg"][1].astype(int) - gray).mean() < 4


def test_odd_sized_frames_keep_their_exact_size(tmp_path: Path) -> None:
    store = _store()
    folder = _write_bag(
        tmp_path / "odd",
        IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        [_raw(store, 0, 641, 481), _raw(store, 1, 1, 1), _raw(store, 2, 3, 7)],
    )
    assert [f.image.shape for f in open_source(folder)] == [(481, 641, 3), (1, 1, 3), (7, 3, 3)]


def _bad_frame_contract(folder: Path, caplog: pytest.LogCaptureFixture, bad_index: int, total: int) -> None:
    """A frame that cannot be decoded: skipped with a warning naming file and frame (the frames after
    it still come), or a ValueError naming file and frame after every earlier frame."""
    with caplog.at_level(logging.WARNING):
        frames, error = _read_all(folder)
    assert [f.index for f in frames][:bad_index] == list(range(bad_index))
    assert all(f.image.ndim == 3 and f.image.shape[0] > 0 and f.image.shape[1] > 0 for f in frames), (
        "an empty image was yielded as a frame"
    )
    if error is not None:
        assert isinstance(error, ValueError), f"{type(error).__name__}: {error}"
        assert folder.name in str(error) and str(bad_index) in str(error), str(error)
    else:
        assert len(frames) == total - 1
        warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert any(folder.name in m for m in warned), f"dropped frame {bad_index} without a warning"


def test_zero_size_image_mid_stream_is_reported_not_yielded(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    store = _store()
    folder = _write_bag(
        tmp_path / "zero_size",
        IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        [_raw(store, 0, 64, 48), _raw(store, 1, 0, 0), _raw(store, 2, 64, 48)],
    )
    _bad_frame_contract(folder, caplog, 1, 3)


def test_short_image_payload_mid_stream_names_file_and_frame(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    store = _store()
    folder = _write_bag(
        tmp_path / "short_payload",
        IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        [_raw(store, 0, 64, 48), _raw(store, 1, 64, 48, np.zeros(10, np.uint8)), _raw(store, 2, 64, 48)],
    )
    _bad_frame_contract(folder, caplog, 1, 3)


def test_garbage_jpeg_mid_stream_names_file_and_frame(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import cv2

    store = _store()
    ok, good = cv2.imencode(".jpg", _test_image())
    assert ok
    payloads = [good.reshape(-1), np.frombuffer(b"\xff\xd8 not really a jpeg" * 4, np.uint8), good.reshape(-1)]
    messages = [
        store.types["sensor_msgs/msg/CompressedImage"](header=_header(store, k / FPS), format="jpeg", data=data)
        for k, data in enumerate(payloads)
    ]
    folder = _write_bag(tmp_path / "bad_jpeg", COMPRESSED_TOPIC, "sensor_msgs/msg/CompressedImage", messages)
    _bad_frame_contract(folder, caplog, 1, 3)


def test_resolution_change_mid_bag_reinitialises_the_pipeline_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    from gldt_core.schedule.scheduler import SchedulerConfig
    from gldt_core.system.config import SystemConfig
    from gldt_core.system.gldt_system import GLDTSystem
    from gldt_core.system.runner import run_frames

    class EmptyGlobal:
        def detect(self, previous_bgr: np.ndarray, current_bgr: np.ndarray) -> np.ndarray:
            assert previous_bgr.shape == current_bgr.shape  # never a pair across the size change
            return np.zeros((0, 6))

    store = _store()
    sizes = [(64, 48)] * 4 + [(96, 64)] * 4
    folder = _write_bag(
        tmp_path / "resize",
        IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        [_raw(store, k, w, h) for k, (w, h) in enumerate(sizes)],
    )
    config = SystemConfig(scheduler=SchedulerConfig(local_enabled=False))
    pipeline = GLDTSystem(config, global_detector=EmptyGlobal())
    with caplog.at_level(logging.WARNING, logger="gldt.system"):
        result = run_frames(pipeline, open_source(folder))
    assert result.frames == 8
    assert result.reinitialisations == 1
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "64x48" in warnings[0].getMessage() and "96x64" in warnings[0].getMessage()


# --------------------------------------------------------------------------- camera_info
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_camera_model_refuses_nan_and_inf_in_camera_info(bad: float) -> None:
    from gldt_core.camera import CameraModel, CameraModelError

    k = default_camera_matrix((640, 512)).reshape(-1)
    for position in (0, 2, 4, 5, 8):
        broken = k.copy()
        broken[position] = bad
        with pytest.raises(CameraModelError, match="camera_info.k"):
            CameraModel.from_camera_info(broken)
    distortion = [0.0] * 5
    distortion[1] = bad
    with pytest.raises(CameraModelError, match="camera_info.d"):
        CameraModel.from_camera_info(k, distortion, "plumb_bob")
    assert CameraModel.from_camera_info(k).fx > 0


def test_nan_camera_info_in_a_bag_is_refused_or_dropped_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    store = _store()
    folder = _write_bag(
        tmp_path / "nan_k",
        IMAGE_TOPIC,
        "sensor_msgs/msg/Image",
        [_raw(store, 0, 64, 48), _raw(store, 1, 64, 48)],
        camera_matrix=np.full((3, 3), np.nan),
    )
    with caplog.at_level(logging.WARNING):
        try:
            source = open_source(folder)
        except ValueError as error:
            assert "nan_k" in str(error) and "camera_info" in str(error).lower()
            return
    assert source.camera_matrix is None or np.all(np.isfinite(source.camera_matrix))
    assert any("nan_k" in r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
    assert len(list(source)) == 2
