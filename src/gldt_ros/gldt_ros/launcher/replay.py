"""The ``pipeline`` command's own node: waits for the graph, plays a bag into it, records its outputs.

:class:`GraphDriver` knows the graph's nodes (:data:`gldt_ros.interface.graph.NODES`) and judges
the link reports they publish (:mod:`gldt_ros.interface.graph_links`); the command itself
(:mod:`gldt_ros.launcher.pipeline`) starts and supervises the node processes.

What the player sends, as a camera driver would:

- one image topic, the one the offline bag reader uses (compressed where the bag has both), which
  ``pipeline`` also sets as frame_pair_buffer's ``image_transport``;
- each frame's camera_info before its image (messages of one log time: images last), and the
  bag's first camera_info before the first image even where the bag logged it later, so frame 0
  has its bearings;
- header stamps of images, camera_info and ground truth moved to the wall-clock time of the
  replay's start (:class:`Restamp`; the bag's intervals are kept, and lockstep answers and
  recordings carry the new stamps), unless ``--keep-bag-stamps``: a bag's stamps start near 0, and a
  planner's staleness check rejects every track stamped 1970;
- ``/clock`` (``rosgraph_msgs/Clock``, :class:`ReplayClock`) following the frames: each frame's
  stamp before the frame, and in a paced replay the bag's time in between, every
  :data:`CLOCK_PERIOD_S`. Nodes run with ``use_sim_time:=true`` take their time from it.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from gldt_msgs.msg import TrackArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from gldt_core.io.bag import (
    CAMERA_INFO_TYPE,
    COMPRESSED_TYPE,
    GROUND_TRUTH_TYPE,
    IMAGE_TYPE,
    IMAGE_TYPES,
    bag_channel_types,
    bag_messages,
)
from gldt_core.io.cdr import header_frame_id, header_stamp_ns, with_header_stamp
from gldt_core.io.mcap_file import McapMessage, McapWriter
from gldt_core.io.recording import track_array_frame_and_source
from gldt_core.io.ros_types import typestore
from gldt_ros.interface import qos, topics
from gldt_ros.interface.graph import NODES, WARM_UP_FRAME_ID
from gldt_ros.interface.graph_links import (
    LiveEndpoints,
    missing_links,
    node_endpoint_gids,
    own_link_counts,
    parse_link_counts,
    reporting_nodes_missing,
)
from gldt_ros.launcher.bag_io import message_class
from gldt_ros.launcher.heartbeat import Heartbeats
from gldt_ros.runtime.node_base import STATUS_NAME_PREFIX, freeze_start_up_objects

#: Subscriptions each node creates last, once its models and state are ready: the graph is up when
#: every one of them is matched (node names alone appear before a node finished starting).
READY_SUBSCRIPTIONS = {
    topics.FRAME_TICKS: 1,  # jptrack_tracker
    topics.TRACK_PREDICTIONS: 1,  # mode_scheduler
    topics.SCHEDULER_STATE: 1,  # frame_pair_buffer
    topics.FRAME_PAIRS: 1,  # global_detector
    topics.ROI_CROPS: 1,  # local_detector
    topics.DETECTIONS: 2,  # jptrack_tracker, mode_scheduler
}

#: Publishers the graph must have, as this process sees them (the other half of being up).
READY_PUBLISHERS = {
    topics.FRAME_TICKS: 1,  # frame_pair_buffer
    topics.FRAME_PAIRS: 1,  # frame_pair_buffer
    topics.ROI_CROPS: 1,  # frame_pair_buffer
    topics.SCHEDULER_STATE: 1,  # mode_scheduler
    topics.TRACK_PREDICTIONS: 1,  # jptrack_tracker
    topics.DETECTIONS: 2,  # global_detector, local_detector
    topics.TRACKS: 1,  # jptrack_tracker
}

RECORDED_TOPICS = {
    topics.TRACKS: "gldt_msgs/msg/TrackArray",
    topics.DETECTIONS: "gldt_msgs/msg/DetectionArray",
    topics.SCHEDULER_STATE: "gldt_msgs/msg/SchedulerState",
}

#: ``image_transport`` of frame_pair_buffer -> the image type the player sends.
TRANSPORT_TYPES = {"raw": IMAGE_TYPE, "compressed": COMPRESSED_TYPE}
#: Types whose first field is a ``std_msgs/Header``: the player restamps these (:class:`Restamp`).
STAMPED_TYPES = frozenset({*IMAGE_TYPES, CAMERA_INFO_TYPE, GROUND_TRUTH_TYPE})
#: Seconds between ``/clock`` messages while a paced replay waits for its next message.
CLOCK_PERIOD_S = 0.01
#: How often the end of a paced replay looks whether the last answers came [s].
DRAIN_POLL_S = 0.005
#: How long a paced replay still listens after its last answer [s], outside the time it reports:
#: a second answer to a frame (which ``bench.live`` counts) still reaches the recording.
LATE_ANSWER_GRACE_S = 0.5
#: Where rclpy's time source listens (absolute: one clock for every namespace).
CLOCK_TOPIC = "/clock"
#: ``pipeline``'s exit status when a replay lost frames or left them unanswered (:func:`loss_reason`);
#: ``gldt run`` uses the same for input frames it could not read.
LOST_FRAMES_EXIT = 3
#: Share of the asked replay rate below which the summary says the player fell behind.
PACE_KEPT = 0.95
#: Images read ahead when looking for the bag's first camera_info (:func:`bag_head`).
HEAD_IMAGES = 64


def bag_image_transport(bag: Path) -> str | None:
    """The ``image_transport`` that receives ``bag``'s frames: the image type the offline reader
    (:class:`gldt_core.io.bag.BagSource`) plays, compressed where the bag has both; ``None``
    without images. Read from the files' summaries, else from the messages up to the first image."""
    types = set(bag_channel_types(bag).values()) & IMAGE_TYPES
    if not types:
        for message in bag_messages(bag):
            if message.msgtype in IMAGE_TYPES:
                types = {message.msgtype}
                break
    if COMPRESSED_TYPE in types:
        return "compressed"
    return "raw" if IMAGE_TYPE in types else None


def bag_head(bag: Path, image_type: str) -> tuple[McapMessage | None, McapMessage | None]:
    """``(the first readable image of image_type, the first camera_info)`` of ``bag``, reading no
    further than both, or :data:`HEAD_IMAGES` images when it has no camera_info near its start."""
    first_image: McapMessage | None = None
    images = 0
    for message in readable_head(bag_messages(bag, log_time_order=True)):
        if message.msgtype == CAMERA_INFO_TYPE and unreadable_reason(message) is None:
            return first_image, message
        if message.msgtype == image_type:
            # Only the first image is deserialised whole (the replay skips an unreadable one and
            # so must this); the later ones are counted, not read.
            if first_image is None and unreadable_reason(message) is None:
                first_image = message
            images += 1
            if images >= HEAD_IMAGES:
                break
    return first_image, None


def warm_up_image(image: McapMessage, stamp_ns: int) -> bytes:
    """CDR bytes of the warm-up frame (:data:`~gldt_ros.interface.graph.WARM_UP_FRAME_ID`): ``image``
    (the bag's first) with that frame_id and ``stamp_ns``."""
    from dataclasses import replace

    store = typestore()
    message = store.deserialize_cdr(image.data, image.msgtype)
    seconds, nanoseconds = divmod(max(0, stamp_ns), 1_000_000_000)
    stamp = replace(message.header.stamp, sec=seconds, nanosec=nanoseconds)
    message = replace(message, header=replace(message.header, stamp=stamp, frame_id=WARM_UP_FRAME_ID))
    return bytes(store.serialize_cdr(message, image.msgtype))


def readable_head(messages: Iterator[McapMessage]) -> Iterator[McapMessage]:
    """``messages`` up to any damage, which ends them quietly (the replay reports it)."""
    try:
        yield from messages
    except ValueError:
        return


def head_channel_types(bag: Path, image_type: str, limit: int = 10_000) -> dict[str, str]:
    """``topic -> type`` of the messages at ``bag``'s start, read forward up to its first message of
    ``image_type`` (at most ``limit`` messages, and never past damage): the channels of a bag whose
    files have no readable summary (:func:`~gldt_core.io.bag.bag_channel_types` is empty then)."""
    types: dict[str, str] = {}
    for count, message in enumerate(readable_head(bag_messages(bag))):
        types.setdefault(message.topic, message.msgtype)
        if message.msgtype == image_type or count + 1 >= limit:
            break
    return types


def unreadable_reason(message: McapMessage) -> str | None:
    """Why the player cannot send ``message`` (its bytes are not a valid message of its type, as the
    offline reader judges them), or ``None``. Only the types the player restamps are checked."""
    if message.msgtype not in STAMPED_TYPES:
        return None
    try:
        header_stamp_ns(message.data)
        typestore().deserialize_cdr(message.data, message.msgtype)
    except Exception as error:  # noqa: BLE001 - rosbags raises several types on bad bytes
        return f"{type(error).__name__}: {error}"
    return None


def frame_ordered(messages: Iterable[McapMessage]) -> Iterator[McapMessage]:
    """``messages`` (in log-time order) with each run of equal log times reordered so that its
    images come last: a frame's camera_info (and ground truth), logged at the frame's time, then
    reaches the graph before the frame. Otherwise in the same order."""
    group: list[McapMessage] = []
    for message in messages:
        if group and message.log_time_ns != group[0].log_time_ns:
            yield from sorted(group, key=lambda m: m.msgtype in IMAGE_TYPES)  # stable: keeps the rest's order
            group = []
        group.append(message)
    yield from sorted(group, key=lambda m: m.msgtype in IMAGE_TYPES)


def loss_reason(
    unreadable: int, unreadable_frames: int, damage: str | None, unanswered: int, lockstep: bool, undecodable: int = 0
) -> str | None:
    """One line saying why a replay lost frames or left them unanswered, or ``None`` when it did
    neither (``pipeline`` then exits 0, else :data:`LOST_FRAMES_EXIT`). Frames skipped by plan
    (answered by prediction while the global detector was busy) and frames answered by prediction
    at the tracker's ``answer_deadline`` are the documented degradation, not a loss;
    ``undecodable`` images, answered the same way, are."""
    reasons = []
    if unreadable:
        reasons.append(f"{unreadable} unreadable bag message(s) skipped ({unreadable_frames} of them frames)")
    if undecodable:
        reasons.append(f"{undecodable} image(s) the graph could not decode (answered by prediction)")
    if damage:
        reasons.append(f"the bag ends in damage ({damage})")
    if unanswered:
        how = "given up after --frame-timeout or a restart" if lockstep else "sent but never answered"
        reasons.append(f"{unanswered} frame(s) without tracks ({how})")
    return "; ".join(reasons) or None


def answer_source(track_array: bytes) -> int | None:
    """``source`` of a ``TrackArray`` (CDR bytes): what measured its frame (``SOURCE_*``)."""
    try:
        return track_array_frame_and_source(track_array)[1]
    except ValueError:
        return None


class Restamp:
    """The header stamps a replay sends: the bag's plus one fixed offset, which maps the bag's first
    frame to the wall-clock time the replay starts (``keep``: no offset). Intervals stay exact, in
    nanoseconds; stamps before the bag's first frame are clamped at 0, which a stamp cannot go below."""

    def __init__(self, first_stamp_ns: int | None, keep: bool, now_ns: int | None = None) -> None:
        if keep or first_stamp_ns is None:
            self.offset_ns = 0
        else:
            self.offset_ns = (time.time_ns() if now_ns is None else now_ns) - first_stamp_ns

    def stamp_ns(self, bag_stamp_ns: int) -> int:
        return max(0, bag_stamp_ns + self.offset_ns)

    def message(self, message: McapMessage) -> bytes:
        """The message's CDR bytes as sent: restamped where its type starts with a header."""
        if self.offset_ns == 0 or message.msgtype not in STAMPED_TYPES:
            return message.data
        return with_header_stamp(message.data, self.stamp_ns(header_stamp_ns(message.data)))


class ReplayClock:
    """``/clock`` of a replay: publishes a time only when it is later than the last one sent."""

    def __init__(self, node: Node) -> None:
        # Reliable matches rclpy's best-effort /clock subscription as well as reliable ones.
        self.publisher = node.create_publisher(
            Clock, CLOCK_TOPIC, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        )
        self.last_ns = -1

    def advance(self, stamp_ns: int) -> None:
        if stamp_ns > self.last_ns:
            self.last_ns = stamp_ns
            seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
            self.publisher.publish(Clock(clock=Time(sec=seconds, nanosec=nanoseconds)))


class GraphDriver(Node):
    """Replays a bag (paced or in lockstep with ``/gldt/tracks``) and records the outputs.

    In lockstep a restarted node (:meth:`note_restarted`) pauses the replay until the new process
    is linked into the graph: the frame in flight is given up at once, and the next one goes out
    only when every link is matched again, so it is answered instead of vanishing between a node
    and a peer that has not discovered it yet. A paced replay does not wait (a camera would not).
    """

    def __init__(self, args: argparse.Namespace) -> None:
        super().__init__("gldt_pipeline")
        self.args = args
        #: The nodes whose links a replay waits for (every node of the graph).
        self.graph_nodes = list(NODES)
        #: The image type the player sends (``pipeline`` picks the bag's, :func:`bag_image_transport`).
        self.image_type = TRANSPORT_TYPES[getattr(args, "image_transport", None) or "raw"]
        self.clock: ReplayClock | None = None
        self._answered: set[int] = set()
        #: Lockstep: stamps of the frames this player sent and still waits for. An answer stamped
        #: otherwise is another graph's (or one given up) and never answers this run's frame.
        self._awaiting: set[int] = set()
        self.unmatched_answers = 0
        self._published_at: dict[int, float] = {}
        self.latencies_s: list[float] = []
        self._answered_cv = threading.Condition()
        self.tracks_received = 0
        #: Frames this player sent that ``/gldt/tracks`` answered (a paced replay's loss count), and
        #: how many of them by each ``TrackArray.source`` (``SOURCE_PREDICTED``: skipped by plan;
        #: ``SOURCE_LATE``: answered at the tracker's deadline).
        self.frames_answered = 0
        self.frames_by_source: dict[int, int] = {}
        self._warm_up_answered = False
        #: Why frames of the last replay were lost or unanswered, in one line, or ``None``.
        self.loss: str | None = None
        #: The damage the last replay's bag ended in, or ``None``.
        self.damage: str | None = None
        # Newest header stamp received per recorded topic: a lockstep replay closes the recording
        # only once every topic has caught up with the last frame (see wait_until_recorded).
        self._newest_recorded: dict[str, int] = {}
        self.recorder = McapWriter(args.record) if args.record else None
        self._closed = False
        # The tracks answer the frames; the other topics are only listened to for a recording, so
        # that without one their writers in the graph have no reader here to serialise them for.
        listened = RECORDED_TOPICS if self.recorder is not None else {topics.TRACKS: RECORDED_TOPICS[topics.TRACKS]}
        for topic, msgtype in listened.items():
            self.create_subscription(
                message_class(msgtype),
                topic,
                self._make_record_callback(topic, msgtype),
                qos.RELIABLE,
                raw=True,
            )
        self._bag_publishers: dict[str, object] = {}
        # Each node's latest /diagnostics status (latched, so none is missed): its matched peers
        # tell when the graph is linked, its counters go into reports.
        self._statuses: dict[str, DiagnosticStatus] = {}
        self._statuses_lock = threading.Lock()
        self.create_subscription(
            DiagnosticArray,
            topics.DIAGNOSTICS,
            self._on_diagnostics,
            QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL),
        )
        # Restarted nodes the lockstep replay has not relinked yet: name -> endpoint ids of the
        # dead process, which peers keep seeing until its DDS lease runs out.
        self._restarted: dict[str, dict[str, set[bytes]]] = {}
        #: Told of every status received: the supervisor's watch on the node processes (``pipeline`` sets it).
        self.heartbeats: Heartbeats | None = None

    def _on_diagnostics(self, array: DiagnosticArray) -> None:
        for status in array.status:
            if status.name.startswith(STATUS_NAME_PREFIX) and status.hardware_id == self.get_namespace():
                with self._statuses_lock:
                    self._statuses[status.name[len(STATUS_NAME_PREFIX) :]] = status
                if self.heartbeats is not None:
                    self.heartbeats.note_status(status.name[len(STATUS_NAME_PREFIX) :], status.values)

    def node_statuses(self) -> dict[str, dict[str, str]]:
        """The latest ``/diagnostics`` key/values of each node of this graph (``inputs``, ...)."""
        with self._statuses_lock:
            statuses = dict(self._statuses)
        return {name: {pair.key: pair.value for pair in status.values} for name, status in statuses.items()}

    def note_restarted(self, names: Sequence[str]) -> None:
        """The supervisor is about to restart the process of nodes ``names`` (called before the new
        process starts, so nothing seen here is the new one's): forget their last statuses (their
        links were the dead process's) and, in lockstep, stop waiting for the frame in flight and
        relink first. A group's nodes are noted together, so the relink waits for all of them."""
        dead_endpoints = {name: node_endpoint_gids(self, name, self.get_namespace()) for name in names}
        with self._statuses_lock:
            for name in names:
                self._statuses.pop(name, None)
        if self.args.lockstep:
            with self._answered_cv:
                self._restarted.update(dead_endpoints)
                self._answered_cv.notify_all()

    def _relink_after_restarts(self, stop: threading.Event, dead: Callable[[], list[str]]) -> str | None:
        """If nodes were restarted, block until each new process is visible and every link of
        the graph is matched again (at most ``--startup-timeout``); returns what happened, in words."""
        with self._answered_cv:
            restarted = dict(self._restarted)
        if not restarted:
            return None
        began = time.monotonic()
        deadline = began + self.args.startup_timeout
        waiting = set(restarted)
        while waiting and not stop.is_set() and time.monotonic() < deadline and not waiting & set(dead()):
            waiting = {name for name in waiting if not self._new_process_visible(name, restarted[name])}
            if waiting:
                stop.wait(0.02)
        dead_gids = {gid for endpoints in restarted.values() for gids in endpoints.values() for gid in gids}
        linked = not waiting and self.wait_until_linked(
            self.graph_nodes, stop, max(0.0, deadline - time.monotonic()), dead_endpoints=dead_gids
        )
        with self._answered_cv:
            for name, endpoints in restarted.items():
                if self._restarted.get(name) is endpoints:
                    del self._restarted[name]
        names = ", ".join(sorted(restarted))
        if not linked:
            return f"graph not linked again {time.monotonic() - began:.2f} s after restarting {names}; going on"
        return f"graph linked again {time.monotonic() - began:.2f} s after restarting {names}"

    def _new_process_visible(self, name: str, dead_endpoints: dict[str, set[bytes]]) -> bool:
        """Whether this process sees the restarted node's own endpoints (not the dead ones) on
        every topic the dead process had."""
        if not dead_endpoints:
            return bool(node_endpoint_gids(self, name, self.get_namespace()))
        # Unnamed endpoints count: DDS matches a new process's endpoints about a second before
        # the graph API learns their owner, and wait_until_linked judges the links themselves.
        now = node_endpoint_gids(self, name, self.get_namespace(), topics=dead_endpoints, include_unnamed=True)
        return all(now.get(topic, set()) - gids for topic, gids in dead_endpoints.items())

    def _make_record_callback(self, topic: str, msgtype: str) -> Callable[[bytes], None]:
        def callback(raw: bytes) -> None:
            now = self.get_clock().now().nanoseconds
            stamp = header_stamp_ns(raw)
            if header_frame_id(raw) == WARM_UP_FRAME_ID:  # not part of the run: never recorded or counted
                if topic == topics.TRACKS:
                    with self._answered_cv:
                        self._warm_up_answered = True
                        self._answered_cv.notify_all()
                return
            if self.recorder is not None:
                try:
                    self.recorder.write(self.resolve_topic_name(topic), msgtype, raw, now)
                except ValueError:
                    if not self._closed:
                        raise
                    return  # a message that raced close(): the run is over, the recording complete
                with self._answered_cv:
                    self._newest_recorded[topic] = max(stamp, self._newest_recorded.get(topic, stamp))
                    self._answered_cv.notify_all()
            if topic == topics.TRACKS:
                received = time.monotonic()
                with self._answered_cv:
                    self.tracks_received += 1
                    if self.args.lockstep:  # only lockstep waits on answers; free runs must not grow a set
                        if stamp in self._awaiting:
                            self._answered.add(stamp)
                        else:  # a frame given up (it came late), or none of this run's
                            self.unmatched_answers += 1
                    published = self._published_at.pop(stamp, None)
                    if published is not None:
                        self.frames_answered += 1
                        source = answer_source(raw)
                        if source is not None:
                            self.frames_by_source[source] = self.frames_by_source.get(source, 0) + 1
                        self.latencies_s.append(received - published)
                    self._answered_cv.notify_all()

        return callback

    def wait_for_nodes(self, names: list[str], timeout_s: float, dead: Callable[[], list[str]]) -> bool:
        """Block until every node name is visible in the graph; report a node that died instead."""
        deadline = time.monotonic() + timeout_s
        wanted = {"/" + name.strip("/") for name in names}
        while time.monotonic() < deadline:
            gone = dead()
            if gone:
                print(f"pipeline: node(s) {', '.join(gone)} exited during start-up", flush=True)
                return False
            present = {(namespace.rstrip("/") + "/" + name) for name, namespace in self.get_node_names_and_namespaces()}
            if (
                wanted <= present
                and all(self.count_subscribers(topic) >= count for topic, count in READY_SUBSCRIPTIONS.items())
                and all(self.count_publishers(topic) >= count for topic, count in READY_PUBLISHERS.items())
            ):
                return True
            time.sleep(0.1)
        print(f"pipeline: nodes not up after {timeout_s:.0f} s: {sorted(wanted - present)}", flush=True)
        return False

    def _publisher(self, topic: str, msgtype: str):
        if topic not in self._bag_publishers:
            reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
            # Relative, so a namespaced graph (one per camera) gets the bag inside its namespace.
            self._bag_publishers[topic] = self.create_publisher(message_class(msgtype), topic.lstrip("/"), reliable)
        return self._bag_publishers[topic]

    def _prepare_publishers(self, stop: threading.Event, timeout_s: float = 10.0) -> None:
        """Create every publisher up front and wait until every link of the graph is matched.

        Without this the first frames would be published before DDS discovery finished and be
        lost: a reliable publisher only delivers to subscriptions it has already matched, and the
        nodes' own links (tracker to scheduler, scheduler to buffer, ...) match on their own time.
        """
        image_publishers = []
        # Without a readable summary (a cut recording) the types of the bag's first messages.
        channel_types = bag_channel_types(self.args.bag) or head_channel_types(self.args.bag, self.image_type)
        for topic, msgtype in channel_types.items():
            if msgtype in IMAGE_TYPES and msgtype != self.image_type:
                continue  # the other transport: not played (see replay)
            try:
                publisher = self._publisher(topic, msgtype)
            except ValueError as error:
                self.get_logger().warning(f"not replaying topic {topic}: {error}")
                continue
            if msgtype in IMAGE_TYPES:
                image_publishers.append(publisher)
        deadline = time.monotonic() + timeout_s
        while image_publishers and not stop.is_set() and time.monotonic() < deadline:
            if any(p.get_subscription_count() > 0 for p in image_publishers):
                break
            time.sleep(0.05)
        else:
            if image_publishers and not stop.is_set():
                self.get_logger().warning(f"no subscriber matched the bag's image topic after {timeout_s:.0f} s")
            return
        self.wait_until_linked(self.graph_nodes, stop, max(0.0, deadline - time.monotonic()))

    def wait_until_linked(
        self, node_names: list[str], stop: threading.Event, timeout_s: float, dead_endpoints: set[bytes] | None = None
    ) -> bool:
        """Block until each named node, and this one, has matched every endpoint this process sees
        on its topics (:mod:`gldt_ros.interface.graph_links`), but ``dead_endpoints`` (those of
        killed processes, visible until their lease runs out); on timeout log what is missing and go on."""
        observer = LiveEndpoints(self, dead_endpoints) if dead_endpoints else self
        deadline = time.monotonic() + timeout_s
        missing: list[str] = []
        while not stop.is_set():
            with self._statuses_lock:
                statuses = dict(self._statuses)
            reports = {name: counts for name, status in statuses.items() if (counts := parse_link_counts(status))}
            silent = reporting_nodes_missing(node_names, reports)
            reports[self.get_name()] = own_link_counts(self)
            missing = [f"{name}: no link report yet" for name in silent] + missing_links(observer, reports)
            if not missing:
                self.get_logger().info(
                    f"every graph link matched after {timeout_s - (deadline - time.monotonic()):.2f} s"
                )
                return True
            if time.monotonic() >= deadline:
                break
            time.sleep(0.02)
        if missing:
            self.get_logger().warning(f"graph links not all matched after {timeout_s:.1f} s: {'; '.join(missing)}")
        return False

    def replay(self, stop: threading.Event, dead: Callable[[], list[str]]) -> str:
        """Play the bag (module docstring: which topics, in which order, with which stamps, and the
        clock); return a one-line summary."""
        if self.clock is None:
            self.clock = ReplayClock(self)
        prepare_start = time.monotonic()
        self._prepare_publishers(stop)
        print(
            f"pipeline: graph linked to the player in {time.monotonic() - prepare_start:.1f} s; "
            "replaying (start-up is not counted in the rates and latencies below)",
            flush=True,
        )
        frames = 0
        first_sent: tuple[float, int] | None = None  # (monotonic, bag log time [ns]) of the first frame sent
        last_sent: tuple[float, int] | None = None
        skipped_topics: set[str] = set()
        waited_out = 0
        unreadable = unreadable_frames = 0
        self.damage = None
        with self._answered_cv:
            self.frames_answered = 0
            self.frames_by_source = {}
        first_image, first_camera_info = bag_head(self.args.bag, self.image_type)
        keep_stamps = bool(getattr(self.args, "keep_bag_stamps", False))
        first_image_ns: int | None = None
        if first_image is not None:
            first_image_ns = header_stamp_ns(first_image.data)
            if not stop.is_set():  # stamped 1 s before the first frame (restamped as the replay will be)
                warm_up_ns = Restamp(first_image_ns, keep_stamps).stamp_ns(first_image_ns) - 1_000_000_000
                self.warm_up(first_image, warm_up_ns, stop)
        freeze_start_up_objects()  # the player and recorder are paced: no collector pause mid-replay
        restamp = Restamp(first_image_ns, keep=keep_stamps)
        camera_info_sent = False
        start_wall = time.monotonic()
        first_log_ns: int | None = None
        clock_offset_ns = 0  # this replay's stamps minus the bag's log times: the clock between frames
        last_stamp: int | None = None
        try:
            for message in frame_ordered(self._bag_stream()):
                if stop.is_set():
                    break
                if message.msgtype in IMAGE_TYPES and message.msgtype != self.image_type:
                    if message.topic not in skipped_topics:
                        skipped_topics.add(message.topic)
                        self.get_logger().info(f"not replaying {message.topic}: the graph reads {self.image_type}")
                    continue
                try:
                    publisher = self._publisher(message.topic, message.msgtype)
                except ValueError as error:
                    if message.topic not in skipped_topics:
                        skipped_topics.add(message.topic)
                        self.get_logger().warning(f"not replaying topic {message.topic}: {error}")
                    continue
                reason = unreadable_reason(message)
                if reason is None:
                    try:
                        data = restamp.message(message)
                    except ValueError as error:
                        reason = str(error)
                if reason is not None:  # skipped, as the offline reader skips it; in lockstep nothing waits for it
                    unreadable += 1
                    unreadable_frames += message.msgtype in IMAGE_TYPES
                    self.get_logger().warning(
                        f"skipped an unreadable {message.topic} message logged at {message.log_time_ns} ns: {reason}"
                    )
                    continue
                if first_log_ns is None:
                    first_log_ns = message.log_time_ns
                    first_stamp = header_stamp_ns(data) if message.msgtype in STAMPED_TYPES else None
                    clock_offset_ns = (first_stamp if first_stamp is not None else restamp.offset_ns) - first_log_ns
                if not self.args.lockstep:
                    due = start_wall + (message.log_time_ns - first_log_ns) / 1e9 / self.args.rate
                    self._paced_wait(due, stop, start_wall, first_log_ns + clock_offset_ns)
                if message.msgtype == CAMERA_INFO_TYPE:
                    camera_info_sent = True
                if message.msgtype in IMAGE_TYPES:
                    last_stamp = header_stamp_ns(data)
                    relinked = self._relink_after_restarts(stop, dead) if self.args.lockstep else None
                    if relinked is not None:
                        print(f"pipeline: {relinked}; next frame stamped {last_stamp}", flush=True)
                    self.clock.advance(last_stamp)
                    if not camera_info_sent and first_camera_info is not None:
                        # The bag logged its first camera_info after this frame: send it first.
                        info = self._publisher(first_camera_info.topic, first_camera_info.msgtype)
                        info.publish(with_header_stamp(first_camera_info.data, last_stamp))
                    camera_info_sent = True
                    self.note_published(last_stamp)
                    if self.args.lockstep:
                        with self._answered_cv:
                            self._awaiting.add(last_stamp)
                publisher.publish(data)
                if message.msgtype in IMAGE_TYPES:
                    frames += 1
                    last_sent = (time.monotonic(), message.log_time_ns)
                    first_sent = first_sent or last_sent
                    if self.args.lockstep and last_stamp is not None and not self._wait_answer(last_stamp, stop, dead):
                        waited_out += 1
        except ValueError as error:  # not the bag's damage (_bag_stream ends at that): a message the player cannot send
            self.damage = self.damage or str(error)
            self.get_logger().error(f"replay stopped: {error}")
        if not self.args.lockstep:
            self.drain(frames, stop)
        elif last_stamp is not None:
            self.wait_until_recorded(last_stamp, stop)
        elapsed = time.monotonic() - start_wall
        if not self.args.lockstep:
            stop.wait(LATE_ANSWER_GRACE_S)  # not in the replay's time: see the constant
        self.frames_published = frames
        unanswered = waited_out if self.args.lockstep else max(0, frames - self.frames_answered)
        self.loss = loss_reason(
            unreadable,
            unreadable_frames,
            self.damage,
            unanswered,
            bool(self.args.lockstep),
            self.frames_by_source.get(TrackArray.SOURCE_UNREADABLE, 0),
        )
        latency = ""
        if self.latencies_s:
            import numpy as np

            p50, p99 = np.percentile(np.asarray(self.latencies_s) * 1000.0, [50, 99])
            # In lockstep the tracker has no answer deadline: every frame waits for its own detections,
            # a slow GD frame included, so this is not what a live run's deadline keeps it under.
            where = " (lockstep: no answer deadline)" if self.args.lockstep else ""
            latency = f"; camera-to-tracks latency{where} p50 {p50:.0f} ms, p99 {p99:.0f} ms"
        rate = ""
        if first_sent is not None and last_sent is not None and frames > 1:
            sent_s = max(last_sent[0] - first_sent[0], 1e-9)
            bag_s = max((last_sent[1] - first_sent[1]) / 1e9, 1e-9)
            pace = "as fast as answered" if self.args.lockstep else f"asked {self.args.rate:g}x the bag's"
            rate = (
                f" at {(frames - 1) / sent_s:.1f} fps (the bag's {(frames - 1) / bag_s:.1f} fps, {pace}: "
                f"x{bag_s / sent_s:.2f} achieved)"
            )
            if not self.args.lockstep and bag_s / sent_s < PACE_KEPT * self.args.rate:
                rate += f"; the player could not keep x{self.args.rate:g} the bag's pace"
        skipped = self.frames_by_source.get(TrackArray.SOURCE_PREDICTED, 0)
        undecodable = self.frames_by_source.get(TrackArray.SOURCE_UNREADABLE, 0)
        late = self.frames_by_source.get(TrackArray.SOURCE_LATE, 0)
        predicted = ", ".join(
            text
            for count, text in (
                (skipped, f"{skipped} skipped by plan while the global detector was busy"),
                (late, f"{late} at the tracker's answer_deadline, their detections still to come"),
                (undecodable, f"{undecodable} undecodable"),
            )
            if count
        )
        predicted = f" ({predicted}: answered by prediction)" if predicted else ""
        answered = frames - unanswered
        return (
            f"pipeline: sent {frames} frames in {elapsed:.2f} s{rate}; answered {answered}{predicted}, "
            f"{unanswered} frames without an answer; {self.tracks_received} track messages{latency}"
            + (f"; {self.unmatched_answers} answers to frames not awaited ignored" if self.unmatched_answers else "")
            + (f"; {unreadable} unreadable bag messages skipped ({unreadable_frames} frames)" if unreadable else "")
            + ("; the bag ends in damage" if self.damage else "")
        )

    def warm_up(self, image: McapMessage, stamp_ns: int, stop: threading.Event) -> bool:
        """Send the warm-up frame (``image``, the bag's first, as :func:`warm_up_image` at
        ``stamp_ns``) and wait for its tracks, at most ``--frame-timeout``; say how long it took.
        Start-up, not replay: the first inference of each model and the first message of each
        link are paid here, and every node starts afresh after it."""
        began = time.monotonic()
        with self._answered_cv:
            self._warm_up_answered = False
        self._publisher(image.topic, image.msgtype).publish(warm_up_image(image, stamp_ns))
        deadline = began + self.args.frame_timeout
        with self._answered_cv:
            while not self._warm_up_answered and not stop.is_set() and time.monotonic() < deadline:
                self._answered_cv.wait(0.05)
            answered = self._warm_up_answered
        took = time.monotonic() - began
        if answered:
            print(f"pipeline: warm-up frame answered in {took:.2f} s (start-up, not counted below)", flush=True)
        elif not stop.is_set():
            print(f"pipeline: no answer to the warm-up frame after {took:.1f} s; replaying anyway", flush=True)
        return answered

    def _bag_stream(self) -> Iterator[McapMessage]:
        """The bag's messages in log-time order (a forward scan: no summary needed), ending at the
        first damage with one error line; :attr:`damage` then says what it was."""
        try:
            yield from bag_messages(self.args.bag, log_time_order=True)
        except ValueError as error:
            self.damage = str(error)
            self.get_logger().error(f"{error}; the replay ends here")

    def _paced_wait(self, due: float, stop: threading.Event, start_wall: float, clock_start_ns: int) -> None:
        """Wait until ``due`` (monotonic), moving ``/clock`` along the bag's time meanwhile."""
        assert self.clock is not None
        while not stop.is_set():
            now = time.monotonic()
            self.clock.advance(clock_start_ns + int(max(0.0, now - start_wall) * self.args.rate * 1e9))
            if now >= due:
                return
            stop.wait(min(due - now, CLOCK_PERIOD_S))

    def _wait_answer(self, stamp_ns: int, stop: threading.Event, dead: Callable[[], list[str]]) -> bool:
        deadline = time.monotonic() + self.args.frame_timeout
        with self._answered_cv:
            try:
                while stamp_ns not in self._answered:
                    if self._restarted:
                        self.get_logger().warning(f"no tracks for frame stamped {stamp_ns} ns: a node was restarted")
                        return False
                    if stop.is_set() or time.monotonic() > deadline or dead():
                        self.get_logger().warning(f"no tracks for frame stamped {stamp_ns} ns; going on")
                        return False
                    self._answered_cv.wait(0.05)
                self._answered.discard(stamp_ns)
                return True
            finally:
                self._awaiting.discard(stamp_ns)

    def wait_until_recorded(self, stamp_ns: int, stop: threading.Event, timeout_s: float = 2.0) -> bool:
        """Wait until every recorded topic has delivered a message stamped ``stamp_ns`` or later.

        The last frame's tracks can reach this node before its detections and scheduler state do:
        they come from other writers, on other topics, and the executor serves them on other
        threads. Closing the recording at the tracks would then lose the last frame's other
        outputs. False after ``timeout_s`` (a frame given up after a restart has none to wait for).
        """
        if self.recorder is None:
            return True
        deadline = time.monotonic() + timeout_s
        with self._answered_cv:
            while any(self._newest_recorded.get(topic, -1) < stamp_ns for topic in RECORDED_TOPICS):
                remaining = deadline - time.monotonic()
                if remaining <= 0 or stop.is_set():
                    return False
                self._answered_cv.wait(min(remaining, 0.05))
        return True

    def note_published(self, stamp_ns: int) -> None:
        """Remember when the camera frame stamped ``stamp_ns`` went out, for its camera-to-tracks
        latency; at most 1000 are kept (frames the graph skipped are forgotten, oldest first)."""
        with self._answered_cv:
            self._published_at[stamp_ns] = time.monotonic()
            if len(self._published_at) > 1000:
                del self._published_at[next(iter(self._published_at))]

    def drain(self, frames: int, stop: threading.Event, quiet_s: float = 1.0, limit_s: float | None = None) -> None:
        """After a paced replay, wait until the graph has answered ``frames`` frames or gone quiet
        for ``quiet_s`` (and at most ``limit_s`` when given). It returns as soon as the last answer
        comes: the replay's time that ``pipeline`` prints ends there, not a quiet period later."""
        start = time.monotonic()
        last, quiet_since = self.tracks_received, start
        while not stop.is_set() and self.tracks_received < frames:
            now = time.monotonic()
            if limit_s is not None and now - start >= limit_s:
                break
            if self.tracks_received != last:
                last, quiet_since = self.tracks_received, now
            elif now - quiet_since >= quiet_s:
                break
            stop.wait(DRAIN_POLL_S)

    def close(self) -> None:
        """Close the recording; messages still arriving are no longer recorded."""
        self._closed = True
        if self.recorder is not None:
            self.recorder.close()
