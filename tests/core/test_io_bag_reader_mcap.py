"""BagSource over the MCAP walk (gldt_core.io.mcap_file): compressed chunks, chunk CRCs, frames
that lose their ground truth.

Bags here are written with the ``mcap`` library (not with :func:`gldt_core.io.bag.write_bag`),
so the reader is checked against an independent writer, with every chunk option it offers. The
fault-injection contract itself (truncation, garbage, bad frames) is tests/faults/test_faults_bags.py.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gldt_core.io.bag import GROUND_TRUTH_TOPIC, GROUND_TRUTH_TYPE, IMAGE_TOPIC, IMAGE_TYPE
from gldt_core.io.sources import open_source

FPS = 30.0


def _store() -> Any:
    from gldt_core.io.ros_types import typestore

    return typestore()


def _header(store: Any, index: int) -> Any:
    ns = int(round(index * 1e9 / FPS))
    stamp = store.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")


def _image(index: int) -> np.ndarray:
    """A small BGR image unique to ``index`` (so a swapped or repeated frame shows)."""
    rng = np.random.default_rng(100 + index)
    return rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)


def _write_mcap(path: Path, frames: int, *, compression: str = "none", with_gt: bool = False) -> Path:
    """``frames`` bgr8 images (and optionally one GroundTruthArray each), one message per chunk."""
    from mcap.writer import CompressionType, Writer

    store = _store()
    kind = {"none": CompressionType.NONE, "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}[compression]
    with path.open("wb") as stream:
        writer = Writer(stream, chunk_size=1, compression=kind, enable_crcs=True)
        writer.start(profile="ros2", library="test")
        image_channel = writer.register_channel(IMAGE_TOPIC, "cdr", writer.register_schema(IMAGE_TYPE, "ros2msg", b""))
        gt_channel = writer.register_channel(
            GROUND_TRUTH_TOPIC, "cdr", writer.register_schema(GROUND_TRUTH_TYPE, "ros2msg", b"")
        )
        for index in range(frames):
            ns = int(round(index * 1e9 / FPS))
            pixels = _image(index)
            message = store.types[IMAGE_TYPE](
                header=_header(store, index),
                height=6,
                width=8,
                encoding="bgr8",
                is_bigendian=0,
                step=24,
                data=pixels.reshape(-1),
            )
            writer.add_message(image_channel, ns, store.serialize_cdr(message, IMAGE_TYPE), ns)
            if with_gt:
                target = store.types["gldt_msgs/msg/GroundTruthObject"](
                    id=7, class_id=1, center_x=4.0, center_y=3.0, width=2.0, height=2.0, visibility=1.0
                )
                truth = store.types[GROUND_TRUTH_TYPE](
                    header=_header(store, index), frame_index=index, objects=[target]
                )
                writer.add_message(gt_channel, ns, store.serialize_cdr(truth, GROUND_TRUTH_TYPE), ns)
        writer.finish()
    return path


@pytest.mark.parametrize("compression", ["none", "zstd", "lz4"])
def test_frames_of_every_chunk_compression_are_read_exactly(tmp_path: Path, compression: str) -> None:
    path = _write_mcap(tmp_path / f"{compression}.mcap", 5, compression=compression)
    source = open_source(path)
    frames = list(source)
    assert len(source) == 5 and source.size == (8, 6) and source.fps == pytest.approx(FPS)
    assert [f.index for f in frames] == [0, 1, 2, 3, 4]
    for index, frame in enumerate(frames):
        assert np.array_equal(frame.image, _image(index))
        assert frame.stamp == pytest.approx(index / FPS, abs=1e-9)


def test_a_chunk_whose_crc_does_not_match_is_reported_as_damage(tmp_path: Path) -> None:
    """A flipped pixel byte keeps every length intact: only the chunk CRC can tell."""
    path = _write_mcap(tmp_path / "crc.mcap", 5)
    data = bytearray(path.read_bytes())
    where = bytes(data).find(_image(3).tobytes())
    assert where > 0
    data[where + 5] ^= 0xFF
    path.write_bytes(bytes(data))
    frames, error = [], None
    try:
        for frame in open_source(path):
            frames.append(frame)
    except ValueError as caught:
        error = caught
    assert [f.index for f in frames] == [0, 1, 2]
    assert error is not None and "crc.mcap" in str(error) and "CRC" in str(error) and "after frame 2" in str(error)


def test_a_frame_whose_ground_truth_is_in_the_damaged_part_is_not_yielded_without_it(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Frame 2's image chunk is intact but its ground-truth chunk is cut off: yielding frame 2
    with no ground truth would be a silent error in every metric, so the damage starts there."""
    path = _write_mcap(tmp_path / "cut.mcap", 4, with_gt=True)
    data = path.read_bytes()
    store = _store()
    truth = store.types[GROUND_TRUTH_TYPE](
        header=_header(store, 2),
        frame_index=2,
        objects=[
            store.types["gldt_msgs/msg/GroundTruthObject"](
                id=7, class_id=1, center_x=4.0, center_y=3.0, width=2.0, height=2.0, visibility=1.0
            )
        ],
    )
    where = data.find(store.serialize_cdr(truth, GROUND_TRUTH_TYPE))
    assert where > data.find(_image(2).tobytes()) > 0
    path.write_bytes(data[: where + 10])

    source = open_source(path)
    assert len(source) == 2
    with caplog.at_level(logging.WARNING):
        assert source.ground_truth[:, 0].tolist() == [1.0, 2.0]
    assert any("cut.mcap" in r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING)
    frames = []
    with pytest.raises(ValueError, match=r"cut\.mcap: damaged after frame 1 "):
        for frame in source:
            frames.append(frame)
    assert [f.index for f in frames] == [0, 1]
    assert all(len(f.ground_truth) == 1 for f in frames)
