"""Sample bags: rosbag2 (MCAP storage) with camera images, camera_info and ground truth.

Written and read with ``rosbags`` (no ROS installation), with the Jazzy typestore plus the
project's ``gldt_msgs`` types from :func:`gldt_core.io.ros_types.typestore`. Topics:

- ``/camera/image_raw/compressed`` (``sensor_msgs/CompressedImage``, JPEG) or
  ``/camera/image_raw`` (``sensor_msgs/Image``, ``bgr8``),
- ``/camera/camera_info`` (``sensor_msgs/CameraInfo``, pinhole ``K``),
- ``/gldt/ground_truth`` (``gldt_msgs/GroundTruthArray``, full-frame pixel boxes).

All three share each frame's header stamp; ``frame_id`` is ``camera``. A bag is written into a
temporary folder beside the target and renamed only once complete, so a failure never leaves a
bag without its ``metadata.yaml``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from gldt_core.data.frame import Frame, FrameSource, empty_ground_truth

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
    roi = store.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    return store.types[CAMERA_INFO_TYPE](
        header=header, height=height, width=width, distortion_model="plumb_bob",
        d=np.zeros(5), k=np.asarray(k, float).reshape(9), r=np.eye(3).reshape(9),
        p=projection.reshape(12), binning_x=0, binning_y=0, roi=roi,
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
                id=int(track_id), class_id=int(max(class_id, 0)) if class_id >= 0 else 1,
                center_x=float(x + w / 2), center_y=float(y + h / 2), width=float(w),
                height=float(h), visibility=float(visibility if visibility >= 0 else 1.0),
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
                        header=header, height=height, width=width, encoding="bgr8", is_bigendian=0,
                        step=width * 3, data=np.ascontiguousarray(image).reshape(-1),
                    )
                writer.write(image_conn, timestamp, store.serialize_cdr(message, image_type))
                writer.write(info_conn, timestamp,
                             store.serialize_cdr(_camera_info(store, header, size, k), CAMERA_INFO_TYPE))
                writer.write(gt_conn, timestamp,
                             store.serialize_cdr(_ground_truth(store, header, frame), GROUND_TRUTH_TYPE))
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


def _seconds(stamp: Any) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def _decode_image(message: Any, msgtype: str) -> np.ndarray:
    import cv2

    if msgtype == COMPRESSED_TYPE:
        image = cv2.imdecode(np.frombuffer(message.data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"cannot decode compressed image of format {message.format!r}")
        return image
    data = np.frombuffer(message.data, np.uint8)
    encoding = message.encoding.lower()
    channels = {"bgr8": 3, "rgb8": 3, "mono8": 1, "bgra8": 4, "rgba8": 4}.get(encoding)
    if channels is None:
        raise ValueError(f"unsupported image encoding {message.encoding!r} (expected bgr8/rgb8/mono8)")
    rows = data.reshape(message.height, message.step)[:, : message.width * channels]
    image = rows.reshape(message.height, message.width, channels)
    conversions = {"rgb8": cv2.COLOR_RGB2BGR, "mono8": cv2.COLOR_GRAY2BGR,
                   "bgra8": cv2.COLOR_BGRA2BGR, "rgba8": cv2.COLOR_RGBA2BGR}
    if encoding in conversions:
        return cv2.cvtColor(np.ascontiguousarray(image), conversions[encoding])
    return image.copy()


def _gt_rows(message: Any) -> np.ndarray:
    if not message.objects:
        return empty_ground_truth()
    return np.array(
        [[message.frame_index + 1, o.id, o.center_x - o.width / 2, o.center_y - o.height / 2,
          o.width, o.height, 1, o.class_id, round(float(o.visibility), 6), -1] for o in message.objects],
        dtype=np.float64,
    )


class BagSource(FrameSource):
    """Frames of a bag written by :func:`write_bag` (or any bag with the same topics)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        from rosbags.rosbag2 import Reader

        from gldt_core.io.ros_types import typestore

        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"bag not found: {self.path}")
        bag_dir = self.path.parent if self.path.is_file() else self.path
        if not (bag_dir / "metadata.yaml").is_file():
            raise ValueError(f"{bag_dir} is not a rosbag2 folder (no metadata.yaml)")
        self._store = typestore()
        self._bag_dir = bag_dir
        self.name = bag_dir.name
        with Reader(bag_dir) as reader:
            topics = {c.topic: c for c in reader.connections}
            if COMPRESSED_TOPIC in topics:
                self.image_topic = COMPRESSED_TOPIC
            elif IMAGE_TOPIC in topics:
                self.image_topic = IMAGE_TOPIC
            else:
                raise ValueError(
                    f"{bag_dir}: no {IMAGE_TOPIC} or {COMPRESSED_TOPIC} topic "
                    f"(topics: {sorted(topics)})"
                )
            self._count = sum(c.msgcount for c in reader.connections if c.topic == self.image_topic)
            self._gt_by_stamp: dict[int, Any] = {}
            self.camera_matrix = None
            wanted = [c for c in reader.connections if c.topic in (GROUND_TRUTH_TOPIC, CAMERA_INFO_TOPIC)]
            info_size: tuple[int, int] | None = None
            for connection, _, raw in reader.messages(connections=wanted):
                message = self._store.deserialize_cdr(raw, connection.msgtype)
                key = int(round(_seconds(message.header.stamp) * 1e9))
                if connection.topic == GROUND_TRUTH_TOPIC:
                    self._gt_by_stamp[key] = message
                elif self.camera_matrix is None:
                    self.camera_matrix = np.asarray(message.k, float).reshape(3, 3)
                    info_size = (int(message.width), int(message.height))
            image_conns = [c for c in reader.connections if c.topic == self.image_topic]
            stamps = []
            first_size = None
            for connection, timestamp, raw in reader.messages(connections=image_conns):
                stamps.append(timestamp)
                if first_size is None:
                    first = _decode_image(self._store.deserialize_cdr(raw, connection.msgtype), connection.msgtype)
                    first_size = (first.shape[1], first.shape[0])
                if len(stamps) >= 2 and first_size is not None and info_size is not None:
                    break
        self.size = first_size or info_size or (0, 0)
        if len(stamps) >= 2 and stamps[1] > stamps[0]:
            self.fps = 1e9 / (stamps[1] - stamps[0])
        else:
            self.fps = 30.0

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[Frame]:
        from rosbags.rosbag2 import Reader

        with Reader(self._bag_dir) as reader:
            connections = [c for c in reader.connections if c.topic == self.image_topic]
            for index, (connection, _, raw) in enumerate(reader.messages(connections=connections)):
                message = self._store.deserialize_cdr(raw, connection.msgtype)
                image = _decode_image(message, connection.msgtype)
                stamp = _seconds(message.header.stamp)
                gt_message = self._gt_by_stamp.get(int(round(stamp * 1e9)))
                rows = _gt_rows(gt_message) if gt_message is not None else empty_ground_truth()
                if len(rows):
                    rows[:, 0] = index + 1
                yield Frame(index=index, stamp=stamp, image=image, ground_truth=rows)

    @property
    def ground_truth(self) -> np.ndarray:
        """All ground-truth rows, frame numbers following image order (1-based)."""
        stamps = sorted(self._gt_by_stamp)
        tables = []
        for index, key in enumerate(stamps):
            rows = _gt_rows(self._gt_by_stamp[key])
            if len(rows):
                rows[:, 0] = index + 1
                tables.append(rows)
        return np.concatenate(tables) if tables else empty_ground_truth()


def read_bag_frames(path: str | os.PathLike[str]) -> Iterator[Frame]:
    """Yield the frames (image, stamp, ground truth) of a bag; see :class:`BagSource`."""
    yield from BagSource(path)
