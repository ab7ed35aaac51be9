"""gldt_ros.interface.graph_links: what a node says it has matched, and how ``pipeline`` judges a
graph connected."""

from __future__ import annotations

import time

import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from gldt_ros.interface.graph_links import (  # noqa: E402
    MATCHED_PUBLISHERS,
    MATCHED_SUBSCRIPTIONS,
    UNKNOWN_NODE_NAME,
    LiveEndpoints,
    link_key_values,
    missing_links,
    node_endpoint_gids,
    own_link_counts,
    parse_link_counts,
    reporting_nodes_missing,
)


class SeenEndpoints:
    """What an observing process sees on each topic (stands in for a node's graph queries)."""

    def __init__(self, subscriptions: dict[str, int], publishers: dict[str, int]) -> None:
        self.subscriptions, self.publishers = subscriptions, publishers

    def count_subscribers(self, topic: str) -> int:
        return self.subscriptions.get(topic, 0)

    def count_publishers(self, topic: str) -> int:
        return self.publishers.get(topic, 0)


class GraphWithOwners:
    """An observer's graph queries over ``(kind, topic, node name, gid)`` endpoint rows."""

    def __init__(self, rows: list[tuple[str, str, str, bytes]]) -> None:
        self.rows = rows
        self.topics_listed = 0

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        self.topics_listed += 1
        return [(topic, ["any"]) for topic in sorted({row[1] for row in self.rows})]

    def _infos(self, kind: str, topic: str) -> list[object]:
        from types import SimpleNamespace

        namespace = lambda name: "_NODE_NAMESPACE_UNKNOWN_" if name == UNKNOWN_NODE_NAME else "/"  # noqa: E731
        return [
            SimpleNamespace(node_name=name, node_namespace=namespace(name), endpoint_gid=list(gid))
            for k, t, name, gid in self.rows
            if k == kind and t == topic
        ]

    def get_publishers_info_by_topic(self, topic: str) -> list[object]:
        return self._infos("pub", topic)

    def get_subscriptions_info_by_topic(self, topic: str) -> list[object]:
        return self._infos("sub", topic)


def test_endpoint_ids_of_a_node_and_of_endpoints_whose_owner_is_not_known_yet() -> None:
    graph = GraphWithOwners(
        [
            ("pub", "/gldt/rois", "mode_scheduler", b"old-rois"),
            ("sub", "/gldt/detections", "mode_scheduler", b"old-dets"),
            ("pub", "/gldt/rois", UNKNOWN_NODE_NAME, b"new-rois"),  # the restarted process, name not in yet
            ("sub", "/gldt/detections", "jptrack_tracker", b"tracker-dets"),
            ("pub", "/diagnostics", "mode_scheduler", b"diag"),  # infrastructure: never counted
        ]
    )
    assert node_endpoint_gids(graph, "mode_scheduler", "/") == {
        "/gldt/rois": {b"old-rois"},
        "/gldt/detections": {b"old-dets"},
    }
    with_unnamed = node_endpoint_gids(graph, "mode_scheduler", "/", include_unnamed=True)
    assert with_unnamed == {"/gldt/rois": {b"old-rois", b"new-rois"}, "/gldt/detections": {b"old-dets"}}
    listed = graph.topics_listed
    only_rois = node_endpoint_gids(graph, "mode_scheduler", "/", topics=["/gldt/rois"], include_unnamed=True)
    assert only_rois == {"/gldt/rois": {b"old-rois", b"new-rois"}}
    assert graph.topics_listed == listed, "named topics must be queried directly, not by listing the graph"


def test_link_counts_survive_the_diagnostics_round_trip_and_foreign_keys_are_ignored() -> None:
    counts = {MATCHED_SUBSCRIPTIONS + "/gldt/tracks": 2, MATCHED_PUBLISHERS + "/gldt/detections": 1}
    status = DiagnosticStatus(
        name="gldt/jptrack_tracker",
        values=[
            KeyValue(key="inputs", value="12"),
            *link_key_values(counts),
            KeyValue(key=MATCHED_PUBLISHERS + "/x", value="n/a"),
        ],
    )
    assert parse_link_counts(status) == counts


def test_a_link_is_missing_until_the_node_matched_every_endpoint_the_observer_sees() -> None:
    observer = SeenEndpoints(subscriptions={"/gldt/tracks": 2}, publishers={"/gldt/detections": 2})
    reports = {
        "jptrack_tracker": {MATCHED_SUBSCRIPTIONS + "/gldt/tracks": 1, MATCHED_PUBLISHERS + "/gldt/detections": 2},
        "mode_scheduler": {MATCHED_PUBLISHERS + "/gldt/detections": 1},
    }
    assert missing_links(observer, reports) == [
        "jptrack_tracker: /gldt/tracks matched 1 of 2 subscriptions",
        "mode_scheduler: /gldt/detections matched 1 of 2 publishers",
    ]
    reports["jptrack_tracker"][MATCHED_SUBSCRIPTIONS + "/gldt/tracks"] = 2
    reports["mode_scheduler"][MATCHED_PUBLISHERS + "/gldt/detections"] = 2
    assert missing_links(observer, reports) == []
    assert reporting_nodes_missing(["jptrack_tracker", "local_detector"], reports) == ["local_detector"]


def test_the_endpoints_of_a_killed_process_do_not_hold_a_relink_up() -> None:
    """A killed process's endpoints stay visible until its lease runs out; the new process cannot
    match them, so judged against them the relink after a restart would wait out the lease."""
    graph = GraphWithOwners(
        [
            ("pub", "/gldt/scheduler/state", "mode_scheduler", b"dead-state"),
            ("pub", "/gldt/scheduler/state", "mode_scheduler", b"new-state"),
            ("sub", "/gldt/scheduler/state", "frame_pair_buffer", b"dead-buffer"),
            ("sub", "/gldt/scheduler/state", "frame_pair_buffer", b"new-buffer"),
        ]
    )
    reports = {
        "frame_pair_buffer": {MATCHED_PUBLISHERS + "/gldt/scheduler/state": 1},
        "mode_scheduler": {MATCHED_SUBSCRIPTIONS + "/gldt/scheduler/state": 1},
    }
    everything = LiveEndpoints(graph, set())
    assert missing_links(everything, reports) == [
        "frame_pair_buffer: /gldt/scheduler/state matched 1 of 2 publishers",
        "mode_scheduler: /gldt/scheduler/state matched 1 of 2 subscriptions",
    ]
    assert missing_links(LiveEndpoints(graph, {b"dead-state", b"dead-buffer"}), reports) == []


def test_own_link_counts_follow_dds_matching_and_leave_out_infrastructure_topics() -> None:
    rclpy.init()
    try:
        talker = rclpy.create_node("links_talker")
        listener = rclpy.create_node("links_listener")
        publisher = talker.create_publisher(String, "/links_test/chatter", 10)
        before = own_link_counts(talker)
        assert set(before) == {MATCHED_SUBSCRIPTIONS + "/links_test/chatter"}, before
        listener.create_subscription(String, "/links_test/chatter", lambda _: None, 10)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and publisher.get_subscription_count() == 0:
            time.sleep(0.05)
        assert own_link_counts(talker) == {MATCHED_SUBSCRIPTIONS + "/links_test/chatter": 1}
        assert own_link_counts(listener) == {MATCHED_PUBLISHERS + "/links_test/chatter": 1}
        assert missing_links(listener, {"links_talker": own_link_counts(talker)}) == []
        talker.destroy_node()
        listener.destroy_node()
    finally:
        rclpy.shutdown()


def test_a_node_republishes_its_diagnostics_as_soon_as_a_peer_is_matched() -> None:
    """With a 60 s diagnostics period, only the on-change report can tell of the new detector."""
    from diagnostic_msgs.msg import DiagnosticArray
    from gldt_msgs.msg import DetectionArray
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from gldt_ros.interface import qos
    from gldt_ros.nodes import mode_scheduler
    from gldt_ros.runtime.spin import start_spin_thread

    rclpy.init()
    try:
        scheduler = mode_scheduler.create_node(cli_args=["--ros-args", "-p", "diagnostics_period:=60.0"])
        probe = rclpy.create_node("links_probe")
        reports: list[dict[str, int]] = []
        latched = QoSProfile(
            depth=20, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )

        def on_diagnostics(array: DiagnosticArray) -> None:
            reports.extend(parse_link_counts(s) for s in array.status if s.name == "gldt/mode_scheduler")

        probe.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, latched)
        executor = MultiThreadedExecutor(num_threads=2)
        executor.add_node(scheduler)
        executor.add_node(probe)
        thread = start_spin_thread(executor)
        key = MATCHED_PUBLISHERS + "/gldt/detections"
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not reports:
            time.sleep(0.05)
        assert reports and reports[-1][key] == 0, reports
        probe.create_publisher(DetectionArray, "/gldt/detections", qos.RELIABLE)
        while time.monotonic() < deadline and reports[-1][key] == 0:
            time.sleep(0.05)
        assert reports[-1][key] == 1, reports
        executor.shutdown(timeout_sec=2.0)
        thread.join(timeout=5.0)  # no callback may still run on a node being destroyed
        scheduler.destroy_node()
        probe.destroy_node()
    finally:
        rclpy.shutdown()
