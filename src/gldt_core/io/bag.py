"""Sample bags: rosbag2 (MCAP storage) with camera images, camera_info and ground truth.

Written with ``rosbags`` and read with :func:`gldt_core.io.mcap_file.read_mcap`, a strict streaming
walk over the MCAP records (no ROS installation; see :class:`BagSource` for what happens with
damaged files), messages (de)serialized with the Jazzy typestore plus the project's ``gldt_msgs``
types from :func:`gldt_core.io.ros_types.typestore`. The graph's player reads bags raw through
:func:`bag_messages`. Topics:

- ``/camera/image_raw/compressed`` (``sensor_msgs/CompressedImage``, JPEG) or
  ``/camera/image_raw`` (``sensor_msgs/Image``, ``bgr8``),
- ``/camera/camera_info`` (``sensor_msgs/CameraInfo``, pinhole ``K``),
- ``/gldt/ground_truth`` (``gldt_msgs/GroundTruthArray``, full-frame pixel boxes).

All three share each frame's header stamp; ``frame_id`` is ``camera``. A bag is written into a
temporary folder beside the target and renamed only once complete, so a failure never leaves a
bag without its ``metadata.yaml``.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gldt_core.io.frame import Frame, FrameSource, empty_ground_truth
from gldt_core.io.mcap_file import McapDamageError, McapMessage, read_mcap, summary_channel_types

IMAGE_TOPIC = "/camera/image_raw"
COMPRESSED_TOPIC = "/camera/image_raw/compressed"
CAMERA_INFO_TOPIC = "/camera/camera_info"
GROUND_TRUTH_TOPIC = "/gldt/ground_truth"
FRAME_ID = "camera"

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
GROUND_TRUTH_TYPE = "gldt_msgs/msg/GroundTruthArray"
GROUND_TRUTH_OBJECT_TYPE = "gldt_msgs/msg/GroundTruthObject"


@dataclass(frozen=True)
class BagSummary:
    """What :func:`write_bag` wrote."""

    path: Path
    frames: int
    ground_truth_rows: int
    compressed: bool
    bytes: int


def default_camera_matrix(size: tuple[int, int], hfov_deg: float = 60.0) -> np.ndarray:
    """A plausible pinhole K when the source has none (centre principal point, given HFOV)."""
    width, height = size
    focal = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return np.array([[focal, 0, (width - 1) / 2.0], [0, focal, (height - 1) / 2.0], [0, 0, 1.0]])


def _stamp(store: Any, seconds: float) -> Any:
    nanoseconds = int(round(seconds * 1e9))
    return store.types["builtin_interfaces/msg/Time"](
        sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000
    )


def _header(store: Any, seconds: float) -> Any:
    return store.types["std_msgs/msg/Header"](stamp=_stamp(store, seconds), frame_id=FRAME_ID)


def _camera_info(store: Any, header: Any, size: tuple[int, int], k: np.ndarray) -> Any:
    width, height = size
    projection = np.zeros((3, 4))
    projection[:, :3] = k
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return store.types[CAMERA_INFO_TYPE](
        header=header,
        height=height,
        width=width,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.asarray(k, float).reshape(9),
        r=np.eye(3).reshape(9),
        p=projection.reshape(12),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def _ground_truth(store: Any, header: Any, frame: Frame) -> Any:
    make_object = store.types[GROUND_TRUTH_OBJECT_TYPE]
    objects = []
    for row in np.asarray(frame.ground_truth, float).reshape(-1, 10):
        _, track_id, x, y, w, h, _, class_id, visibility, _ = row
        if track_id < 0 or track_id > 0xFFFFFFFF:
            raise ValueError(f"frame {frame.index}: ground-truth id {track_id} is not a uint32")
        objects.append(
            make_object(
                id=int(track_id),
                class_id=int(max(class_id, 0)) if class_id >= 0 else 1,
                center_x=float(x + w / 2),
                center_y=float(y + h / 2),
                width=float(w),
                height=float(h),
                visibility=float(visibility if visibility >= 0 else 1.0),
            )
        )
    return store.types[GROUND_TRUTH_TYPE](header=header, frame_index=int(frame.index), objects=objects)


def write_bag(
    path: str | os.PathLike[str],
    frames: Iterable[Frame],
    *,
    size: tuple[int, int],
    camera_matrix: np.ndarray | None = None,
    compressed: bool = True,
    jpeg_quality: int = 90,
    overwrite: bool = False,
) -> BagSummary:
    """Write ``frames`` to a rosbag2 MCAP bag folder at ``path``.

    Every frame's image must be ``size`` (width, height) HxWx3 uint8 BGR. The bag appears at
    ``path`` only when complete; on any error nothing is left behind (and an existing bag is
    untouched unless the new one was written completely and ``overwrite`` is set).
    """
    import cv2
    from rosbags.rosbag2 import StoragePlugin, Writer

    from gldt_core.io.ros_types import typestore

    path = Path(path)
    if path.exists() and not overwrite:
        raise ValueError(f"{path} already exists (pass overwrite=True / --force to replace it)")
    if not 1 <= int(jpeg_quality) <= 100:
        raise ValueError(f"jpeg_quality must be in 1..100, got {jpeg_quality}")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"output folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"output folder {parent} is not writable")
    width, height = size
    k = default_camera_matrix(size) if camera_matrix is None else np.asarray(camera_matrix, float)
    store = typestore()
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.partial-", dir=parent))
    except OSError as error:
        raise ValueError(f"output folder {parent} is not writable ({error.strerror})") from None
    staged_bag = staging / path.name
    count = rows = 0
    try:
        with Writer(staged_bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            image_topic, image_type = (COMPRESSED_TOPIC, COMPRESSED_TYPE) if compressed else (IMAGE_TOPIC, IMAGE_TYPE)
            image_conn = writer.add_connection(image_topic, image_type, typestore=store)
            info_conn = writer.add_connection(CAMERA_INFO_TOPIC, CAMERA_INFO_TYPE, typestore=store)
            gt_conn = writer.add_connection(GROUND_TRUTH_TOPIC, GROUND_TRUTH_TYPE, typestore=store)
            for frame in frames:
                image = frame.image
                if image.dtype != np.uint8 or image.ndim != 3 or image.shape != (height, width, 3):
                    raise ValueError(
                        f"frame {frame.index}: image must be {height}x{width}x3 uint8 BGR, "
                        f"got {image.shape} {image.dtype}"
                    )
                header = _header(store, frame.stamp)
                timestamp = int(round(frame.stamp * 1e9))
                if compressed:
                    ok, encoded = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
                    if not ok:
                        raise ValueError(f"frame {frame.index}: JPEG encoding failed")
                    message = store.types[COMPRESSED_TYPE](header=header, format="jpeg", data=encoded.reshape(-1))
                else:
                    message = store.types[IMAGE_TYPE](
                        header=header,
                        height=height,
                        width=width,
                        encoding="bgr8",
                        is_bigendian=0,
                        step=width * 3,
                        data=np.ascontiguousarray(image).reshape(-1),
                    )
                writer.write(image_conn, timestamp, store.serialize_cdr(message, image_type))
                writer.write(
                    info_conn, timestamp, store.serialize_cdr(_camera_info(store, header, size, k), CAMERA_INFO_TYPE)
                )
                writer.write(
                    gt_conn, timestamp, store.serialize_cdr(_ground_truth(store, header, frame), GROUND_TRUTH_TYPE)
                )
                count += 1
                rows += len(frame.ground_truth)
        if count == 0:
            raise ValueError("no frames to write: a bag needs at least one frame")
        if path.exists():  # overwrite: only now that the new bag is complete
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        os.replace(staged_bag, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    size_bytes = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    return BagSummary(path, count, rows, compressed, size_bytes)


# --------------------------------------------------------------------------- reading
#
# Bags are read with the strict streaming walk of gldt_core.io.mcap_file rather than rosbags'
# Reader: that Reader needs the summary section at the end of the file (a recorder that was killed
# leaves none) and reads every chunk up front, so one damaged byte would make the whole recording
# unreadable. Messages are decoded with the project's rosbags typestore.

LOG = logging.getLogger("gldt.io.bag")

#: The message types a bag's camera topic may carry.
IMAGE_TYPES = frozenset({IMAGE_TYPE, COMPRESSED_TYPE})


def _seconds(stamp: Any) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _decode_image(message: Any, msgtype: str) -> np.ndarray:
    """BGR frame of an Image/CompressedImage; :class:`ImageDecodeError` (a ValueError) if impossible."""
    from gldt_core.io.imaging import decode_compressed_image, decode_raw_image

    if msgtype == COMPRESSED_TYPE:
        return decode_compressed_image(message.data, message.format)
    return decode_raw_image(
        message.data,
        int(message.width),
        int(message.height),
        message.encoding,
        step=int(message.step),
        is_bigendian=bool(message.is_bigendian),
    )


def _gt_rows(message: Any) -> np.ndarray:
    if not message.objects:
        return empty_ground_truth()
    return np.array(
        [
            [
                message.frame_index + 1,
                o.id,
                o.center_x - o.width / 2,
                o.center_y - o.height / 2,
                o.width,
                o.height,
                1,
                o.class_id,
                round(float(o.visibility), 6),
                -1,
            ]
            for o in message.objects
        ],
        dtype=np.float64,
    )


def bag_files(path: str | os.PathLike[str]) -> list[Path]:
    """The MCAP files of a bag folder (in the order metadata.yaml lists them) or of a ``.mcap`` path."""
    import yaml

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag not found: {path}")
    if path.is_file():
        return [path]
    metadata_path = path / "metadata.yaml"
    if not metadata_path.is_file():
        raise ValueError(f"{path} is not a rosbag2 folder (no metadata.yaml)")
    try:
        info = (yaml.safe_load(metadata_path.read_text()) or {}).get("rosbag2_bagfile_information") or {}
    except (yaml.YAMLError, UnicodeDecodeError, AttributeError) as error:
        raise ValueError(f"{metadata_path}: not a readable rosbag2 metadata file ({type(error).__name__})") from None
    storage = info.get("storage_identifier", "mcap")
    if storage != "mcap":
        raise ValueError(f"{path}: storage {storage!r} is not supported (only MCAP bags)")
    names = info.get("relative_file_paths") or sorted(p.name for p in path.glob("*.mcap"))
    files = [path / str(name) for name in names]
    missing = [str(f) for f in files if not f.is_file()]
    if not files or missing:
        raise ValueError(f"{path}: bag file(s) missing: {', '.join(missing) or 'no .mcap file'}")
    return files


class BagSource(FrameSource):
    """Frames of a bag written by :func:`write_bag` (or any MCAP bag with the same topics).

    Robustness contract (a recording must never crash the node or lose frames silently):

    * A damaged file (truncated anywhere, or corrupt record framing): the frames before the damage
      are yielded, then ``ValueError('<file>: damaged after frame N (byte B): ...')``; ``len()``
      counts those frames, ``damage`` holds the details, and :attr:`ground_truth` warns. A frame
      whose ground truth lies in the damaged part counts as damaged (never yielded without it).
      Nothing readable before the damage: ``ValueError`` at open. A file cut only in its summary
      section (after all data) is read in full.
    * A frame that cannot be decoded (unreadable message, 0x0 image, short raw payload, bad JPEG):
      skipped with a warning naming file and frame; the frames after it still come, with their
      own indices (``index`` counts image messages, so a skipped frame leaves a gap).
    * A non-image type on the image topic: ``ValueError`` at open naming topic, type and file.
    * No camera_info / ground-truth topic: no camera matrix / empty ground truth. A CameraInfo
      whose K is not a usable pinhole matrix (NaN, inf, fx <= 0) is ignored with a warning.

    Messages are yielded in file order (the order they were recorded in).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from gldt_core.io.ros_types import typestore

        self.path = Path(path)
        self._files = bag_files(self.path)
        self._bag_dir = self.path.parent if self.path.is_file() else self.path
        self.name = self._bag_dir.name if self.path.is_dir() else self.path.stem
        self._store = typestore()
        self.camera_matrix: np.ndarray | None = None
        self._gt_by_stamp: dict[int, Any] = {}
        self._scan()

    # ---------------------------------------------------------------- opening
    def _messages(self) -> Iterator[McapMessage]:
        for file in self._files:
            yield from read_mcap(file)

    def _deserialize(self, raw: McapMessage) -> Any:
        """The message, or ValueError naming file, topic and type when its bytes do not decode."""
        if raw.channel.encoding != "cdr":
            raise ValueError(f"{raw.path}: {raw.topic} uses message encoding {raw.channel.encoding!r}, not cdr")
        try:
            return self._store.deserialize_cdr(raw.data, raw.msgtype)
        except Exception as error:  # noqa: BLE001 - rosbags raises several types on bad bytes
            raise ValueError(
                f"{raw.path}: {raw.topic} message at byte {raw.offset} is not a "
                f"valid {raw.msgtype} ({type(error).__name__}: {error})"
            ) from None

    def _scan(self) -> None:
        """One pass over the bag: topics, frame count, first size, fps, camera matrix, ground truth."""
        image_logs: dict[str, list[int]] = {COMPRESSED_TOPIC: [], IMAGE_TOPIC: []}
        image_stamps: dict[str, list[int | None]] = {COMPRESSED_TOPIC: [], IMAGE_TOPIC: []}
        image_types: dict[str, str] = {}
        first_size: dict[str, tuple[int, int]] = {}
        topics: set[str] = set()
        info_size: tuple[int, int] | None = None
        bad_k: str | None = None
        self.damage: McapDamageError | None = None
        try:
            for raw in self._messages():
                topic, msgtype = raw.topic, raw.msgtype
                topics.add(topic)
                if topic in image_logs:
                    image_types.setdefault(topic, msgtype)
                    image_logs[topic].append(raw.log_time_ns)
                    stamp = None
                    if msgtype in IMAGE_TYPES:
                        try:
                            message = self._deserialize(raw)
                            stamp = int(round(_seconds(message.header.stamp) * 1e9))
                            if topic not in first_size:
                                image = _decode_image(message, msgtype)
                                first_size[topic] = (image.shape[1], image.shape[0])
                        except ValueError:
                            pass  # reported (with its frame index) when iterating
                    image_stamps[topic].append(stamp)
                elif topic == GROUND_TRUTH_TOPIC and msgtype == GROUND_TRUTH_TYPE:
                    try:
                        message = self._deserialize(raw)
                    except ValueError as error:
                        LOG.warning("%s; its ground truth is lost", error)
                        continue
                    self._gt_by_stamp[int(round(_seconds(message.header.stamp) * 1e9))] = message
                elif topic == CAMERA_INFO_TOPIC and msgtype == CAMERA_INFO_TYPE:
                    try:
                        message = self._deserialize(raw)
                    except ValueError as error:
                        LOG.warning("%s; ignored", error)
                        continue
                    if self.camera_matrix is None:  # the first usable K (a camera's K does not change)
                        try:
                            self.camera_matrix = self._checked_k(message.k)
                        except ValueError as error:
                            bad_k = bad_k or str(error)
                            continue
                        info_size = (int(message.width), int(message.height))
        except McapDamageError as damage:
            self.damage = damage
        if bad_k is not None and self.camera_matrix is None:
            LOG.warning("%s: no usable camera_info (%s); the camera matrix is unknown", self._label, bad_k)
        self.image_topic = next((t for t in (COMPRESSED_TOPIC, IMAGE_TOPIC) if image_logs[t]), None)
        if self.image_topic is None:
            if self.damage is not None:
                raise ValueError(f"{self._damage_text(0)}; no image frame before it") from None
            raise ValueError(
                f"{self._label}: no {IMAGE_TOPIC} or {COMPRESSED_TOPIC} messages (topics: {sorted(topics)})"
            )
        msgtype = image_types[self.image_topic]
        if msgtype not in IMAGE_TYPES:
            raise ValueError(
                f"{self._label}: topic {self.image_topic} carries {msgtype or 'an unknown type'}, "
                f"not {IMAGE_TYPE} or {COMPRESSED_TYPE}"
            )
        self._image_stamps = image_stamps[self.image_topic]
        self._count = len(self._image_stamps)
        if self.damage is not None and self._gt_by_stamp:
            # The last frames before the damage may have lost their ground truth to it (a frame's
            # messages can straddle chunks): they end the readable part rather than come with none.
            while self._count and self._image_stamps[self._count - 1] not in self._gt_by_stamp:
                self._count -= 1
        if self.damage is not None and self._count == 0:
            raise ValueError(f"{self._damage_text(0)}; no complete frame before it")
        self.size = first_size.get(self.image_topic) or info_size or (0, 0)
        logs = image_logs[self.image_topic]
        self.fps = 1e9 / (logs[1] - logs[0]) if len(logs) >= 2 and logs[1] > logs[0] else 30.0

    @property
    def _label(self) -> str:
        return str(self._files[0]) if len(self._files) == 1 else str(self._bag_dir)

    def _damage_text(self, frames_before: int) -> str:
        assert self.damage is not None
        where = f"after frame {frames_before - 1}" if frames_before else "before the first frame"
        return f"{self.damage.path}: damaged {where} (byte {self.damage.offset}): {self.damage.reason}"

    def _checked_k(self, k: Any) -> np.ndarray:
        from gldt_core.camera import CameraModel

        values = np.asarray(k, dtype=np.float64).reshape(-1)
        CameraModel.from_camera_info(values)  # raises CameraModelError (a ValueError) naming camera_info.k
        return values.reshape(3, 3)

    # ---------------------------------------------------------------- reading
    def __len__(self) -> int:
        """Image messages readable (before any damage); undecodable ones are skipped when iterating."""
        return self._count

    def __iter__(self) -> Iterator[Frame]:
        index = -1
        try:
            for raw in self._messages():
                if raw.topic != self.image_topic:
                    continue
                if self.damage is not None and index + 1 >= self._count:
                    raise self.damage
                index += 1
                try:
                    message = self._deserialize(raw)
                    image = _decode_image(message, raw.msgtype)
                except ValueError as error:  # one bad frame must not stop the node
                    reason = str(error).removeprefix(f"{raw.path}: ")
                    LOG.warning("%s: frame %d skipped: %s", raw.path, index, reason)
                    continue
                stamp = _seconds(message.header.stamp)
                gt_message = self._gt_by_stamp.get(int(round(stamp * 1e9)))
                rows = _gt_rows(gt_message) if gt_message is not None else empty_ground_truth()
                if len(rows):
                    rows[:, 0] = index + 1
                yield Frame(index=index, stamp=stamp, image=image, ground_truth=rows)
        except McapDamageError:
            raise ValueError(self._damage_text(index + 1)) from None

    @property
    def ground_truth(self) -> np.ndarray:
        """All ground-truth rows, numbered by the image frame with the same stamp (1-based)."""
        index_of = {stamp: k for k, stamp in enumerate(self._image_stamps) if stamp is not None}
        tables = []
        orphans = 0
        for key in sorted(self._gt_by_stamp, key=lambda s: index_of.get(s, -1)):
            if key not in index_of:
                orphans += 1
                continue
            rows = _gt_rows(self._gt_by_stamp[key])
            if len(rows):
                rows[:, 0] = index_of[key] + 1
                tables.append(rows)
        if self.damage is not None:  # iterating raises it; reading only the ground truth must not hide it
            LOG.warning("%s; ground truth of the %d frames before it only", self._damage_text(self._count), self._count)
        if orphans:
            LOG.warning("%s: %d ground-truth messages match no readable image frame; left out", self._label, orphans)
        return np.concatenate(tables) if tables else empty_ground_truth()


def read_bag_frames(path: str | os.PathLike[str]) -> Iterator[Frame]:
    """Yield the frames (image, stamp, ground truth) of a bag; see :class:`BagSource`."""
    yield from BagSource(path)


def bag_messages(path: str | os.PathLike[str], *, log_time_order: bool = False) -> Iterator[McapMessage]:
    """Every message of a bag, raw (CDR bytes), file after file; by log time within each file
    with ``log_time_order`` (the order a player publishes them in).

    A damaged file yields every message read before the damage, then ``ValueError`` naming the
    file and the byte.
    """
    files = bag_files(path)
    try:
        for file in files:
            yield from read_mcap(file, log_time_order=log_time_order)
    except McapDamageError as damage:
        raise ValueError(
            f"bag {damage.path} is damaged after the messages already read: {damage.reason} (byte {damage.offset})"
        ) from None


def bag_channel_types(path: str | os.PathLike[str]) -> dict[str, str]:
    """``topic -> pkg/msg/Name`` of every channel the bag's files list in their summaries (empty
    for a file without a readable summary: its channels are then learnt while reading it)."""
    types: dict[str, str] = {}
    for file in bag_files(path):
        types.update(summary_channel_types(file))
    return types
