"""A node's long work off the spinning thread (gldt_ros.runtime.worker, GldtNode.call_on_spin_thread):
items worked on in order with the newest kept, results handed back to the spinning thread, the
other nodes of the process answered meanwhile, and a worker that fails ending its process."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy", reason="gldt_ros is installed with the ROS wheels that `make test` installs")

from gldt_ros.runtime.worker import KeepNewestWorker  # noqa: E402
from support import isolated_ros_env  # noqa: E402


def blank_pair(index: int):
    """A FramePair of two grey 640x384 images (the global detector's input size for 640x512 frames)."""
    import numpy as np
    from gldt_msgs.msg import FramePair
    from std_msgs.msg import Header

    from gldt_ros.interface.convert import bgr_to_image

    header = Header(frame_id="camera")
    header.stamp.sec = index
    image = bgr_to_image(np.full((384, 640, 3), 200, np.uint8), header)
    return FramePair(
        header=header,
        frame_index=index,
        previous_frame_index=index,
        full_width=640,
        full_height=384,
        scale=1.0,
        previous=image,
        current=image,
    )


def wait_until(condition, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.005)
    return condition()


class HeldWork:
    """Work that records its items, holding the first one until released."""

    def __init__(self) -> None:
        self.started = threading.Event()
        self.release = threading.Event()
        self.done: list[int] = []

    def __call__(self, item: int) -> None:
        if not self.started.is_set():
            self.started.set()
            self.release.wait(10)
        self.done.append(item)


def busy_worker(depth: int, items: int) -> tuple[KeepNewestWorker[int], HeldWork]:
    """A worker of ``depth`` that gets item 0, then ``items`` - 1 more while busy with it, then is released."""
    work = HeldWork()
    worker: KeepNewestWorker[int] = KeepNewestWorker(work, depth=depth, on_error=lambda error: None, name="test")
    worker.submit(0)
    assert work.started.wait(10)
    for item in range(1, items):
        worker.submit(item)
    work.release.set()
    assert wait_until(worker.idle)
    return worker, work


def test_a_worker_runs_its_items_in_order_and_keeps_only_the_newest_while_busy() -> None:
    worker, work = busy_worker(depth=2, items=5)  # 1 and 2 are replaced by 3 and 4
    assert work.done == [0, 3, 4] and worker.replaced == 2
    worker.stop()
    assert not worker.alive()
    worker.submit(5)  # after stop: not even queued
    assert worker.idle() and work.done == [0, 3, 4]


def test_a_worker_with_room_for_every_item_works_through_all_of_them() -> None:
    """The same busy start with a deeper queue answers every item: the test above can tell them apart."""
    worker, work = busy_worker(depth=4, items=5)
    assert work.done == [0, 1, 2, 3, 4] and worker.replaced == 0
    worker.stop()


def test_an_error_in_the_work_ends_the_worker_and_is_handed_on() -> None:
    errors: list[BaseException] = []
    done: list[int] = []

    def work(item: int) -> None:
        if item == 1:
            raise KeyError("broken model")
        done.append(item)

    worker: KeepNewestWorker[int] = KeepNewestWorker(work, depth=4, on_error=errors.append, name="test")
    for item in range(3):
        worker.submit(item)
    assert wait_until(lambda: not worker.alive())
    assert done == [0] and len(errors) == 1 and isinstance(errors[0], KeyError)
    with pytest.raises(ValueError, match="depth"):
        KeepNewestWorker(work, depth=0, on_error=errors.append, name="test")


def test_the_global_detector_leaves_the_process_free_while_it_works(monkeypatch: pytest.MonkeyPatch) -> None:
    """One events executor spins the global detector and another node, as in ``--processes
    one-process``: while the model is busy with a pair (held until released), the other node's
    messages are still handled; once released, the detections are published from the spinning
    thread."""
    import rclpy
    from gldt_msgs.msg import DetectionArray, FramePair
    from rclpy.context import Context
    from std_msgs.msg import String

    from gldt_ros.interface import topics
    from gldt_ros.interface.qos import RELIABLE
    from gldt_ros.nodes.global_detector import GlobalDetectorNode
    from gldt_ros.runtime.executor import EventsSpinner

    context = Context()
    rclpy.init(context=context, domain_id=int(isolated_ros_env()["ROS_DOMAIN_ID"]))
    spinner = None
    release = threading.Event()
    try:
        detector = GlobalDetectorNode(context=context)
        model_threads: list[int] = []
        original = detector.detector.detect_prepared

        def held(*args, **kwargs):
            model_threads.append(threading.get_ident())
            release.wait(20)
            return original(*args, **kwargs)

        monkeypatch.setattr(detector.detector, "detect_prepared", held)
        publish_threads: list[int] = []
        publisher = detector.publisher

        class RecordingPublisher:
            """The detector's publisher, noting the thread of each publication."""

            def publish(self, message: DetectionArray) -> None:
                publish_threads.append(threading.get_ident())
                publisher.publish(message)

            def get_subscription_count(self) -> int:
                return publisher.get_subscription_count()

        detector.publisher = RecordingPublisher()
        other = rclpy.create_node("other", context=context)
        chatter: list[str] = []
        answers: list[int] = []
        other.create_subscription(String, "chatter", lambda message: chatter.append(message.data), RELIABLE)
        other.create_subscription(
            DetectionArray,
            topics.DETECTIONS,
            lambda message: answers.append(int(message.frame_index)),
            RELIABLE,
        )
        talker = rclpy.create_node("talker", context=context)
        say = talker.create_publisher(String, "chatter", RELIABLE)
        send_pair = talker.create_publisher(FramePair, topics.FRAME_PAIRS, RELIABLE)
        spinner = EventsSpinner(context)
        for node in (detector, other, talker):
            spinner.add_node(node)
        spin_threads: list[int] = []

        def spin() -> None:
            spin_threads.append(threading.get_ident())
            spinner.spin()

        thread = threading.Thread(target=spin, daemon=True)
        thread.start()
        assert wait_until(
            lambda: (
                send_pair.get_subscription_count() > 0
                and say.get_subscription_count() > 0
                and publisher.get_subscription_count() > 0
            )
        )
        send_pair.publish(blank_pair(7))
        assert wait_until(lambda: len(model_threads) == 1)  # the model is busy with frame 7
        say.publish(String(data="while busy"))
        assert wait_until(lambda: chatter == ["while busy"]), "the other node waited for the model"
        assert answers == []
        release.set()
        assert wait_until(lambda: len(answers) == 1)
        assert answers == [7]
        assert publish_threads == [spin_threads[0]] and spin_threads[0] != model_threads[0]
        spinner.shutdown()
        thread.join(5)
        for node in (detector, other, talker):
            node.destroy_node()
        assert not detector.worker.alive()
    finally:
        release.set()  # a failed assertion must not leave the worker held for 20 s
        if spinner is not None:
            spinner.shutdown()
        rclpy.shutdown(context=context)


def run_script(script: str) -> tuple[subprocess.CompletedProcess[str], str]:
    """Run ``script`` in a Python process of its own, on an isolated ROS domain, with this module
    (``blank_pair``) and the tests' support module importable: the process and its output."""
    environment = isolated_ros_env()
    here = Path(__file__).parent
    environment["PYTHONPATH"] = f"{here}:{here.parent}:{environment.get('PYTHONPATH', '')}"
    completed = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=environment
    )
    return completed, completed.stdout + completed.stderr


def test_a_global_detector_whose_model_fails_ends_its_process_with_the_error() -> None:
    """An error off the executor's callbacks must end the node as an error in a callback would
    (exit 1, the error named), not leave a node whose heartbeat goes on without a worker."""
    script = textwrap.dedent(
        """
        import rclpy
        from gldt_msgs.msg import FramePair
        from gldt_ros.interface import topics
        from gldt_ros.interface.qos import RELIABLE
        from gldt_ros.nodes.global_detector import GlobalDetectorNode
        from gldt_ros.runtime.executor import EventsSpinner
        from test_ros_worker import blank_pair

        rclpy.init()
        detector = GlobalDetectorNode()
        def broken(*args, **kwargs):
            raise KeyError("model output 'boxes' missing")
        detector.detector.detect_prepared = broken
        talker = rclpy.create_node("talker")
        send = talker.create_publisher(FramePair, topics.FRAME_PAIRS, RELIABLE)
        spinner = EventsSpinner()
        spinner.add_node(detector)
        spinner.add_node(talker)
        talker.create_timer(0.2, lambda: send.publish(blank_pair(3)))
        spinner.spin()
        print("spin ended without the error")
        """
    )
    completed, output = run_script(script)
    assert completed.returncode == 1, output[-3000:]
    assert "KeyError" in output and "model output 'boxes' missing" in output and "exiting" in output
    assert "spin ended" not in output


def test_a_pair_still_in_the_model_when_the_node_is_destroyed_is_dropped_quietly() -> None:
    """``destroy_node`` waits a second for the model; a pair that takes longer finishes after the
    node is gone, while the executor still spins other nodes. Its result is dropped: no publish on
    a destroyed publisher, no FATAL exit of the process."""
    script = textwrap.dedent(
        """
        import threading, time
        import rclpy
        from gldt_msgs.msg import FramePair
        from gldt_ros.interface import topics
        from gldt_ros.interface.qos import RELIABLE
        from gldt_ros.nodes.global_detector import GlobalDetectorNode
        from gldt_ros.runtime.executor import EventsSpinner
        from test_ros_worker import blank_pair

        rclpy.init()
        detector = GlobalDetectorNode()
        release, started = threading.Event(), threading.Event()
        original = detector.detector.detect_prepared
        def held(*args, **kwargs):
            started.set()
            release.wait(20)
            return original(*args, **kwargs)
        detector.detector.detect_prepared = held
        talker = rclpy.create_node("talker")
        send = talker.create_publisher(FramePair, topics.FRAME_PAIRS, RELIABLE)
        spinner = EventsSpinner()
        spinner.add_node(detector)
        spinner.add_node(talker)
        threading.Thread(target=spinner.spin, daemon=True).start()
        deadline = time.monotonic() + 20
        while send.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        send.publish(blank_pair(3))
        assert started.wait(20), "the model never got the pair"
        spinner.executor.remove_node(detector)
        detector.destroy_node()  # the worker's stop gives up after 1 s: the pair is still held
        release.set()
        time.sleep(1.0)  # the held pair finishes and its result reaches the executor
        print("clean", flush=True)
        spinner.shutdown()
        rclpy.shutdown()
        """
    )
    completed, output = run_script(script)
    assert completed.returncode == 0 and "clean" in output, output[-3000:]
    assert "FATAL" not in output and "exiting" not in output, output[-3000:]
