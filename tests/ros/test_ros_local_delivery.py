"""Messages between the nodes of one process (gldt_ros.runtime.local_delivery): delivered once,
after the publishing callback, to every subscription of the topic and type, while DDS still
carries them to other processes."""

from __future__ import annotations

import select
import subprocess
import sys
import textwrap
import threading
import time

import pytest

pytest.importorskip("rclpy", reason="gldt_ros is installed with the ROS wheels that `make test` installs")

from gldt_ros.runtime.dds_profile import DDS_PROFILE_VARIABLE, shipped_profile  # noqa: E402
from gldt_ros.runtime.local_delivery import LocalDelivery, local_delivery_wanted  # noqa: E402
from support import isolated_ros_env  # noqa: E402


class Tick:
    def __init__(self, value: int) -> None:
        self.value = value


class Other:
    pass


def test_a_message_is_handled_after_the_callback_that_published_it() -> None:
    delivery = LocalDelivery()
    log: list[str] = []

    def on_tick(tick: Tick) -> None:
        log.append(f"tick {tick.value}")
        if tick.value == 1:
            delivery.publish("/b", Tick(2))  # published while handling: queued, not nested
            log.append("on_tick 1 returns")

    delivery.add_subscriber("/a", Tick, on_tick, owner="node a")
    delivery.add_subscriber("/b", Tick, on_tick, owner="node b")
    executor_callback = delivery.dispatching(lambda: (delivery.publish("/a", Tick(1)), log.append("timer returns")))
    executor_callback()
    assert log == ["timer returns", "tick 1", "on_tick 1 returns", "tick 2"]
    assert delivery.delivered == 2


def test_every_subscription_of_the_topic_and_type_gets_it_once_in_order() -> None:
    delivery = LocalDelivery()
    got: dict[str, list[int]] = {"first": [], "second": [], "other type": [], "other topic": []}
    delivery.add_subscriber("/t", Tick, lambda m: got["first"].append(m.value), owner=1)
    delivery.add_subscriber("/t", Tick, lambda m: got["second"].append(m.value), owner=2)
    delivery.add_subscriber("/t", Other, lambda m: got["other type"].append(m), owner=3)
    delivery.add_subscriber("/u", Tick, lambda m: got["other topic"].append(m.value), owner=4)
    for value in (1, 2, 3):
        delivery.publish("/t", Tick(value))  # no callback running: delivered at once
    assert got == {"first": [1, 2, 3], "second": [1, 2, 3], "other type": [], "other topic": []}
    assert delivery.subscriber_count("/t") == 3 and delivery.subscriber_count("/v") == 0


def test_a_destroyed_node_gets_nothing_and_counts_no_more() -> None:
    delivery = LocalDelivery()
    got: list[int] = []
    delivery.add_subscriber("/t", Tick, lambda m: got.append(m.value), owner="gone")
    delivery.add_publisher("/t", object(), owner="gone")
    delivery.add_publisher("/t", object(), owner="stays")
    delivery.forget("gone")
    delivery.publish("/t", Tick(1))
    assert got == [] and delivery.subscriber_count("/t") == 0 and delivery.publisher_count("/t") == 1


def test_a_failing_subscriber_does_not_lose_the_messages_queued_behind_it() -> None:
    delivery = LocalDelivery()
    got: list[int] = []

    def fails(tick: Tick) -> None:
        if tick.value == 1:
            raise RuntimeError("boom")
        got.append(tick.value)

    delivery.add_subscriber("/t", Tick, fails, owner=1)
    burst = delivery.dispatching(lambda: [delivery.publish("/t", Tick(v)) for v in (1, 2)])
    with pytest.raises(RuntimeError, match="boom"):
        burst()  # as an uncaught error escapes an executor's callback
    delivery.publish("/t", Tick(3))
    assert got == [2, 3]


def test_a_publication_from_another_thread_is_refused() -> None:
    delivery = LocalDelivery()
    errors: list[BaseException] = []

    def publish() -> None:
        try:
            delivery.publish("/t", Tick(1))
        except RuntimeError as error:
            errors.append(error)

    worker = threading.Thread(target=publish)
    worker.start()
    worker.join()
    assert len(errors) == 1 and "thread" in str(errors[0])


def test_local_delivery_is_on_unless_turned_off() -> None:
    assert local_delivery_wanted({}) and local_delivery_wanted({"GLDT_LOCAL_DELIVERY": "1"})
    assert not local_delivery_wanted({"GLDT_LOCAL_DELIVERY": "0"})


# A process hosting two GL-DT nodes: the first publishes 3 ticks; the second subscribes. It prints
# what the subscriber got and the nodes' link counts, then waits for stdin before it ends.
GROUP = textwrap.dedent(
    """
    import sys, time
    import rclpy
    from std_msgs.msg import Int32
    from gldt_ros.interface.graph_links import MATCHED_PUBLISHERS, MATCHED_SUBSCRIPTIONS
    from gldt_ros.runtime.dds_profile import use_group_profile_if_shipped
    from gldt_ros.runtime.local_delivery import install_local_delivery
    from gldt_ros.runtime.node_base import GldtNode

    local = use_group_profile_if_shipped()
    if local:
        install_local_delivery()
    rclpy.init()
    writer, reader = GldtNode("mode_scheduler"), GldtNode("jptrack_tracker")
    got = []
    reader.create_subscription(Int32, "probe", lambda m: got.append(m.data), 10)
    publisher = writer.create_publisher(Int32, "probe", 10)
    print("up", flush=True)
    sys.stdin.readline()  # the test's outside subscriber has matched
    end = time.monotonic() + 10.0
    while time.monotonic() < end and publisher.get_subscription_count() < 2:
        rclpy.spin_once(writer, timeout_sec=0.05)
    for value in (1, 2, 3):
        publisher.publish(Int32(data=value))
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        rclpy.spin_once(reader, timeout_sec=0.05)
    counts = writer.diagnostics_status().values + reader.diagnostics_status().values
    links = {kv.key: kv.value for kv in counts if kv.key.endswith("/probe")}
    print("local", local, "got", got, "links", sorted(links.items()), flush=True)
    sys.stdin.readline()
    """
)


@pytest.mark.parametrize("group_profile", [True, False])
def test_nodes_of_one_process_get_each_message_once_and_other_processes_get_it_too(group_profile: bool) -> None:
    """With the group profile, DDS leaves the process's own link to local delivery (one copy per
    message, not two) and still carries the messages to a subscriber in another process; the link
    counts include the process's own peer. Without a shipped profile (a user's own, or none) the
    group uses DDS alone: the same messages, the same counts."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Int32

    env = isolated_ros_env()
    env.pop(DDS_PROFILE_VARIABLE, None)
    if group_profile:
        env[DDS_PROFILE_VARIABLE] = str(shipped_profile())  # the child swaps it for the group profile
    context = Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    outside = rclpy.create_node("outside", context=context)
    received: list[int] = []
    outside.create_subscription(Int32, "probe", lambda m: received.append(m.data), 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(outside)
    group = subprocess.Popen(
        [sys.executable, "-c", GROUP], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert group.stdin is not None and group.stdout is not None
        assert group.stdout.readline().strip() == "up"
        group.stdin.write("\n")
        group.stdin.flush()
        report = ""
        deadline = time.monotonic() + 30.0
        while not report and group.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if select.select([group.stdout], [], [], 0)[0]:
                report = group.stdout.readline()
        end = time.monotonic() + 1.0
        while time.monotonic() < end and len(received) < 3:
            executor.spin_once(timeout_sec=0.05)
        group.communicate("\n", timeout=30)
    finally:
        if group.poll() is None:
            group.kill()
        executor.shutdown()
        outside.destroy_node()
        rclpy.shutdown(context=context)
    assert f"local {group_profile}" in report, report
    assert "got [1, 2, 3]" in report, f"the process's own subscriber, once each: {report}"
    assert received == [1, 2, 3], "another process still gets them over DDS"
    # The writer reaches the reader beside it and the outside subscriber; the reader has one writer.
    assert "('matched_subscriptions:/probe', '2')" in report, report
    assert "('matched_publishers:/probe', '1')" in report, report
