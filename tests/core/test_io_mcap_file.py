"""The one MCAP reader/writer (gldt_core.io.mcap_file): orders, writer round trip, cut files.

Reference orders come from the ``mcap`` library, an independent reader. How :class:`BagSource`
turns damage into frames and errors is tests/faults/test_faults_bags.py and
tests/core/test_io_bag_reader_mcap.py.
"""

from __future__ import annotations

import random
import shutil
import struct
from pathlib import Path

import pytest

from gldt_core.io.bag import IMAGE_TYPES, bag_channel_types, bag_messages
from gldt_core.io.cdr import header_stamp_ns
from gldt_core.io.mcap_file import (
    McapDamageError,
    McapWriter,
    read_mcap,
    ros2_type_name,
    summary_channel_types,
)
from support import SYNTH_BAG

TRACKS = "gldt_msgs/msg/TrackArray"
DETECTIONS = "gldt_msgs/msg/DetectionArray"


def _library_order(path: Path, log_time_order: bool) -> list[tuple[str, int, bytes]]:
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        return [
            (channel.topic, message.log_time, bytes(message.data))
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=log_time_order)
        ]


def _our_order(path: Path, log_time_order: bool) -> list[tuple[str, int, bytes]]:
    return [(m.topic, m.log_time_ns, m.data) for m in read_mcap(path, log_time_order=log_time_order)]


def _shuffled_times_file(path: Path, compression: str, chunk_size: int, seed: int) -> Path:
    """Messages on three channels whose log times wander back and forth across chunks."""
    from mcap.writer import CompressionType, Writer

    rng = random.Random(seed)
    with path.open("wb") as stream:
        writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType[compression])
        writer.start(profile="ros2", library="test")
        channels = [
            writer.register_channel(f"/topic{k}", "cdr", writer.register_schema(f"pkg/msg/Type{k}", "ros2msg", b""))
            for k in range(3)
        ]
        log_time = 1000
        for index in range(400):
            log_time = max(0, log_time + rng.randint(-40, 40))
            payload = bytes([index % 256]) * rng.randint(0, 60)
            writer.add_message(rng.choice(channels), log_time, payload, log_time)
        writer.finish()
    return path


@pytest.mark.parametrize(("compression", "chunk_size"), [("NONE", 1), ("NONE", 500), ("ZSTD", 700), ("LZ4", 3000)])
def test_file_and_log_time_order_match_an_independent_reader(tmp_path: Path, compression: str, chunk_size: int) -> None:
    path = _shuffled_times_file(tmp_path / "shuffled.mcap", compression, chunk_size, seed=chunk_size)
    for log_time_order in (False, True):
        assert _our_order(path, log_time_order) == _library_order(path, log_time_order)
    times = [m.log_time_ns for m in read_mcap(path, log_time_order=True)]
    assert times == sorted(times) and times != [m.log_time_ns for m in read_mcap(path)]


def test_the_sample_bag_reads_in_the_independent_readers_orders() -> None:
    path = SYNTH_BAG / "synth_1080p_multi_uav.mcap"
    for log_time_order in (False, True):
        assert _our_order(path, log_time_order) == _library_order(path, log_time_order)
    assert bag_channel_types(SYNTH_BAG) == {
        "/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
        "/camera/camera_info": "sensor_msgs/msg/CameraInfo",
        "/gldt/ground_truth": "gldt_msgs/msg/GroundTruthArray",
    }


def _cdr_with_stamp(seconds: int, nanoseconds: int, little_endian: bool = True) -> bytes:
    encapsulation = b"\x00\x01\x00\x00" if little_endian else b"\x00\x00\x00\x00"
    return encapsulation + struct.pack("<iI" if little_endian else ">iI", seconds, nanoseconds) + b"rest"


def test_header_stamp_is_read_in_either_byte_order() -> None:
    assert header_stamp_ns(_cdr_with_stamp(3, 5)) == 3_000_000_005
    assert header_stamp_ns(_cdr_with_stamp(3, 5, little_endian=False)) == 3_000_000_005
    with pytest.raises(ValueError, match="too short"):
        header_stamp_ns(b"\x00\x01\x00\x00\x03")


def test_schema_names_become_ros2_type_names() -> None:
    assert ros2_type_name("sensor_msgs/Image") == "sensor_msgs/msg/Image"
    assert ros2_type_name("sensor_msgs/msg/Image") == "sensor_msgs/msg/Image"
    assert ros2_type_name("") == ""
    assert IMAGE_TYPES == {"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"}


def _graph_output(msgtype: str, frame: int) -> bytes:
    """An empty TrackArray or DetectionArray of ``frame``, stamped ``frame`` s, as CDR bytes."""
    from gldt_core.io.ros_types import typestore

    store = typestore()
    stamp = store.types["builtin_interfaces/msg/Time"](sec=frame, nanosec=7)
    header = store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")
    if msgtype == TRACKS:
        message = store.types[TRACKS](header=header, frame_index=frame, source=0, tracks=[])
    else:
        message = store.types[DETECTIONS](
            header=header, frame_index=frame, mode=0, processing_time=0.0, detections=[], rois=[]
        )
    return bytes(store.serialize_cdr(message, msgtype))


def _recording(path: Path, frames: int, chunk_size: int = 256 * 1024) -> list[tuple[str, int, bytes]]:
    """What the graph's recorder writes: two output topics per frame, as raw CDR bytes."""
    writer = McapWriter(path, chunk_size=chunk_size)
    written = []
    for frame in range(frames):
        for topic, msgtype in (("/gldt/tracks", TRACKS), ("/gldt/detections", DETECTIONS)):
            data = _graph_output(msgtype, frame)
            assert header_stamp_ns(data) == frame * 1_000_000_000 + 7
            writer.write(topic, msgtype, data, 1_000 + frame)
            written.append((topic, 1_000 + frame, data))
    writer.close()
    writer.close()  # idempotent
    assert writer.count == 2 * frames
    return written


def test_what_the_writer_writes_reads_back_with_its_types(tmp_path: Path) -> None:
    path = tmp_path / "graph.mcap"
    written = _recording(path, 5)
    assert _our_order(path, False) == written == _library_order(path, False)
    assert {m.msgtype for m in read_mcap(path)} == {TRACKS, DETECTIONS}
    assert summary_channel_types(path) == {"/gldt/tracks": TRACKS, "/gldt/detections": DETECTIONS}


def test_a_cut_recording_gives_every_message_before_the_cut_then_the_damage(tmp_path: Path) -> None:
    """A killed recorder leaves no summary: what its complete chunks hold is still read."""
    from gldt_core.io.recording import iter_recorded

    path = tmp_path / "graph.mcap"
    written = _recording(path, 40, chunk_size=64)
    data = path.read_bytes()
    cut = data.find(written[30][2])  # inside the chunk of message 30
    path.write_bytes(data[:cut])
    assert summary_channel_types(path) == {}
    for log_time_order in (False, True):
        read = []
        with pytest.raises(McapDamageError, match=r"graph\.mcap: .*truncated") as caught:
            for message in read_mcap(path, log_time_order=log_time_order):
                read.append((message.topic, message.log_time_ns, message.data))
        assert read == written[: len(read)] and len(read) >= 28
        assert 0 < caught.value.offset < cut
    stamps = []
    with pytest.raises(ValueError, match=r"recording .*graph\.mcap is damaged after the messages already read"):
        for _, message, _ in iter_recorded(path, "gldt/tracks"):
            stamps.append(message.header.stamp.sec)
    assert stamps == list(range(len(stamps))) and len(stamps) >= 14


def test_a_player_gets_every_message_before_the_damage_in_log_time_order(tmp_path: Path) -> None:
    data = (SYNTH_BAG / "synth_1080p_multi_uav.mcap").read_bytes()
    intact = [(m.topic, m.data) for m in bag_messages(SYNTH_BAG, log_time_order=True)]
    folder = tmp_path / "cut_bag"
    folder.mkdir()
    shutil.copy(SYNTH_BAG / "metadata.yaml", folder / "metadata.yaml")
    (folder / "synth_1080p_multi_uav.mcap").write_bytes(data[: len(data) // 2])
    played = []
    with pytest.raises(ValueError, match=r"bag .*cut_bag/synth_1080p_multi_uav\.mcap is damaged after the messages"):
        for message in bag_messages(folder, log_time_order=True):
            played.append((message.topic, message.data))
    assert 0 < len(played) < len(intact) and played == intact[: len(played)]
    assert bag_channel_types(folder) == {}


def test_a_file_that_is_not_mcap_is_damaged_at_byte_zero(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_bytes(b"not an mcap file at all")
    with pytest.raises(McapDamageError, match="bad magic") as caught:
        list(read_mcap(path, log_time_order=True))
    assert caught.value.offset == 0
    assert summary_channel_types(path) == {}


_KILLED_WRITER = """
import sys, time
sys.path[:0] = [{tests!r}, {tests_root!r}]
from test_io_mcap_file import TRACKS, _graph_output
from gldt_core.io.mcap_file import McapWriter
writer = McapWriter({path!r}, flush_interval_s=0.2)
for frame in range(30):
    writer.write("/gldt/tracks", TRACKS, _graph_output(TRACKS, frame), 1_000 + frame)
print("written", flush=True)
time.sleep(600)
"""


def test_a_writer_killed_with_sigkill_leaves_every_message_older_than_its_flush_interval(tmp_path: Path) -> None:
    """Issue 31: SIGKILL of the recorder after a quiet flush interval loses nothing it wrote;
    its 30 small messages would all sit in one unwritten 256 KiB chunk without the periodic flush."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from gldt_core.io.recording import iter_recorded

    path = tmp_path / "graph.mcap"
    script = _KILLED_WRITER.format(
        tests=str(Path(__file__).parent), tests_root=str(Path(__file__).parents[1]), path=str(path)
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "written"
        time.sleep(0.6)  # three flush intervals
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    assert summary_channel_types(path) == {}, "a killed writer cannot have written its summary"
    frames = []
    with pytest.raises(ValueError, match=r"recording .*graph\.mcap is damaged after the messages already read"):
        for _, message, _ in iter_recorded(path, "gldt/tracks"):
            frames.append(int(message.frame_index))
    assert frames == list(range(30))


def test_the_writer_flushes_on_its_own_while_no_message_comes(tmp_path: Path) -> None:
    import time

    path = tmp_path / "graph.mcap"
    writer = McapWriter(path, flush_interval_s=0.1)
    try:
        writer.write("/gldt/tracks", TRACKS, _graph_output(TRACKS, 0), 1_000)
        deadline = time.monotonic() + 5.0
        while _read_until_damage(path) == [] and time.monotonic() < deadline:
            time.sleep(0.02)
        assert [t for t, _, _ in _read_until_damage(path)] == ["/gldt/tracks"]
    finally:
        writer.close()
    assert [t for t, _, _ in _our_order(path, False)] == ["/gldt/tracks"]
    with pytest.raises(ValueError, match="flush_interval_s must be positive"):
        McapWriter(tmp_path / "other.mcap", flush_interval_s=0)


def _read_until_damage(path: Path) -> list[tuple[str, int, bytes]]:
    read: list[tuple[str, int, bytes]] = []
    try:
        for message in read_mcap(path):
            read.append((message.topic, message.log_time_ns, message.data))
    except McapDamageError:
        pass
    return read


def test_fields_after_the_header_are_read_from_the_bytes_as_rosbags_writes_them() -> None:
    """``after_header_fields`` and ``header_frame_id`` against the typestore's own serialisation,
    for frame_ids of every length modulo the alignment and both byte orders."""
    from dataclasses import replace

    from gldt_core.io.cdr import after_header_fields, header_frame_id
    from gldt_core.io.ros_types import typestore

    store = typestore()
    template = store.types["gldt_msgs/msg/TrackArray"]
    header_type, time_type = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    for frame_id in ("", "c", "cam", "camera", "camera_optical", "gldt_warm_up"):
        for source in (0, 2, 3):
            message = template(
                header=header_type(stamp=time_type(sec=12, nanosec=345), frame_id=frame_id),
                frame_index=2**40 + 7,
                source=source,
                tracks=[],
            )
            for little_endian in (True, False):
                data = bytes(store.serialize_cdr(message, "gldt_msgs/msg/TrackArray", little_endian=little_endian))
                assert after_header_fields(data, "QB") == (2**40 + 7, source)
                assert header_frame_id(data) == frame_id
            assert replace(message, source=source).source == source
    with pytest.raises(ValueError):
        after_header_fields(b"\x00\x01\x00\x00" + b"\x00" * 12, "QB")
