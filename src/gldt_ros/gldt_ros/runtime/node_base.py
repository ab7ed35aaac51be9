"""What every GL-DT node shares: schema-declared parameters, diagnostics, one-line errors.

Each node processes messages in callbacks; a bad message must cost one log line and that message
only, never the node. :meth:`GldtNode.guarded` wraps a callback so that documented errors
(``ValueError`` and its subclasses such as ``ImageDecodeError``) are counted as dropped frames in
the node's ``/diagnostics`` status and logged in one line, repeats of the same kind at most once a
second (:mod:`gldt_ros.runtime.log_throttle`).

Besides the inputs and drops, the status counts the frame pairs the global detector skipped
(``pairs_skipped``) and the messages dropped as late (``stale_dropped``, :class:`StaleMessage`);
both are WARN while they happen (in the period since the last regular status). A node can also
raise a named condition that stays WARN until it clears it (:meth:`GldtNode.set_warning`, e.g. the
tracker's "no valid camera_info").

The diagnostics also carry how many peers each of the node's topics has matched
(:mod:`gldt_ros.interface.graph_links`), republished as soon as that changes: it is how the
``pipeline`` command knows the graph is connected end to end before it sends the first frame.
The periodic status is also the node's heartbeat, with its pid and ``diagnostics_period``: the
``pipeline`` command restarts a node that stops sending it (:mod:`gldt_ros.launcher.heartbeat`).

Every timer of these nodes runs on the steady clock, not on ROS time: the diagnostics, the link
checks and the scheduler's report timeout are about the process, and with ``use_sim_time`` a
ROS-time timer stops whenever ``/clock`` does (before a replay started, or paused in lockstep),
which kept the graph from ever reporting its links. Message stamps and ``get_clock()`` still
follow ``use_sim_time``.

:func:`run_node` is every node's ``main`` (:func:`run_nodes` that of a process hosting several):
it applies the process-wide runtime settings of this package (executor, heap trimming, DDS
profile, stack dumps, bounded teardown) and spins the node.
"""

from __future__ import annotations

import gc
import os
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from gldt_core.system.stamps import StaleMessage
from gldt_ros.interface import qos, topics
from gldt_ros.interface.graph_links import link_key_values, own_link_counts, parse_link_counts
from gldt_ros.interface.params import SCHEMA, ParamSpec
from gldt_ros.launcher.heartbeat import PERIOD_KEY, PID_KEY
from gldt_ros.runtime.dds_profile import use_frames_profile_if_shipped, use_group_profile_if_shipped
from gldt_ros.runtime.executor import EVENTS, executor_kind, quiet_sigint_for_events_executor, spin_nodes
from gldt_ros.runtime.heap_trim import start_heap_trimming, trim_period_from_env
from gldt_ros.runtime.local_delivery import (
    LocalPublisher,
    active_local_delivery,
    install_local_delivery,
    local_delivery_wanted,
    uninstall_local_delivery,
)
from gldt_ros.runtime.log_throttle import LogThrottle
from gldt_ros.runtime.stack_dump import dump_stacks_on_request
from gldt_ros.runtime.teardown_limit import limit_teardown

#: How often a node checks whether its matched peers changed (a cheap count per topic).
LINK_CHECK_PERIOD_S = 0.1
#: A node's ``/diagnostics`` status is named this prefix plus the node name.
STATUS_NAME_PREFIX = "gldt/"
#: Diagnostics keys of the event counters every node reports (0 where a node never has the event):
#: frame pairs the global detector never answered because a newer pair overtook them (counted
#: by frame_pair_buffer, which sends the pairs and sees the answers), and inputs dropped as late.
PAIRS_SKIPPED = "pairs_skipped"
STALE_DROPPED = "stale_dropped"
#: Timer callbacks cut short by a documented error (ValueError), logged in one line as a
#: subscription's are (:meth:`GldtNode.create_timer`).
TIMER_ERRORS = "timer_errors"
#: How each counter reads in a WARN status's message.
_EVENT_TEXT = {
    PAIRS_SKIPPED: "frame pair(s) skipped",
    STALE_DROPPED: "stale input(s) dropped",
    TIMER_ERRORS: "timer callback(s) failed",
}


class GldtNode(Node):
    """Base class: declares the node's parameters from :data:`SCHEMA` and reports diagnostics."""

    def __init__(self, name: str, **kwargs: Any) -> None:
        # Set before Node.__init__, which already creates publishers (rosout, parameter events).
        self._local = active_local_delivery()
        #: Set when the node is being destroyed: work still finishing on another thread is dropped.
        self.closing = False
        super().__init__(name, **kwargs)
        self._specs = {spec.name: spec for spec in SCHEMA[name]}
        for spec in SCHEMA[name]:
            self.declare_parameter(spec.name, spec.default, _descriptor(spec))
            spec.validate(self.get_parameter(spec.name).value)
        self._arrivals: deque[float] = deque(maxlen=120)
        self._processing: deque[float] = deque(maxlen=120)
        self.frames_in = 0
        self.frames_dropped = 0
        self._warned: set[str] = set()
        self._error_lines = LogThrottle()
        # Event counters (totals) and their values at the last regular status: an event since then
        # makes the status WARN. Named conditions raised by set_warning stay WARN until cleared.
        self.events: dict[str, int] = {key: 0 for key in _EVENT_TEXT}
        self._events_reported = dict(self.events)
        self._warnings: dict[str, str] = {}
        self._status_changed = False  # a warning was raised or cleared since the last status
        # Latched, so a process that starts listening late still gets each node's latest status.
        self._diagnostics = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, qos.LATCHED_STATE)
        self._reported_links: dict[str, int] | None = None
        self.create_timer(float(self.param("diagnostics_period")), self._publish_diagnostics)
        self.create_timer(LINK_CHECK_PERIOD_S, self._publish_if_links_changed)

    def param(self, name: str) -> Any:
        """Current value of a schema parameter."""
        return self.get_parameter(name).value

    def guarded(self, callback: Callable[[Any], None], what: str) -> Callable[[Any], None]:
        """Wrap a subscription callback: time it, count it, log documented errors in one line."""

        def wrapper(message: Any) -> None:
            start = time.perf_counter()
            self.frames_in += 1
            self._arrivals.append(time.monotonic())
            try:
                callback(message)
            except ValueError as error:
                self.frames_dropped += 1
                if isinstance(error, StaleMessage):
                    self.count_event(STALE_DROPPED)
                line = self._error_lines.text_for(what, str(error))
                if line is not None:
                    self.get_logger().error(f"dropped {what}: {line}")
            except RuntimeError:
                self._reraise_unless_stopping()
            finally:
                self._processing.append(time.perf_counter() - start)

        return wrapper

    def create_publisher(self, msg_type: Any, topic: str, qos_profile: Any, **kwargs: Any) -> Any:
        """``Node.create_publisher``; in a process with local delivery
        (:mod:`gldt_ros.runtime.local_delivery`) a :class:`LocalPublisher` around it, which also
        hands each message to this process's subscriptions of the topic."""
        publisher = super().create_publisher(msg_type, topic, qos_profile, **kwargs)
        if self._local is None:
            return publisher
        self._local.add_publisher(publisher.topic_name, publisher, owner=self)
        return LocalPublisher(publisher, self._local)

    def create_subscription(self, msg_type: Any, topic: str, callback: Any, qos_profile: Any, **kwargs: Any) -> Any:
        """``Node.create_subscription``; in a process with local delivery the callback also gets
        what this process's own nodes publish on the topic (DDS no longer matches them)."""
        if self._local is None:
            return super().create_subscription(msg_type, topic, callback, qos_profile, **kwargs)
        subscription = super().create_subscription(
            msg_type, topic, self._local.dispatching(callback), qos_profile, **kwargs
        )
        self._local.add_subscriber(subscription.topic_name, msg_type, callback, owner=self)
        return subscription

    def destroy_node(self) -> None:
        self.closing = True
        if self._local is not None:
            self._local.forget(self)
        super().destroy_node()

    def create_timer(
        self,
        timer_period_sec: float,
        callback: Callable[[], None],
        callback_group: Any = None,
        clock: Clock | None = None,
        autostart: bool = True,
    ) -> Any:
        """``Node.create_timer`` on the steady clock unless ``clock`` is given (module docstring:
        it keeps running under ``use_sim_time``), whose callback may be cut short by a stop, as
        :meth:`guarded`'s may: every timer of the graph's nodes publishes (diagnostics, links,
        report timeouts, the tracker's answers at its deadline). A documented error (ValueError)
        is what it is for a subscription too: logged in one line (repeats throttled), counted
        (:data:`TIMER_ERRORS`), and the node goes on; it does not end the process from the timer."""
        what = f"timer {getattr(callback, '__name__', 'callback')}"

        def stop_tolerant() -> None:
            try:
                callback()
            except ValueError as error:
                self.count_event(TIMER_ERRORS)
                line = self._error_lines.text_for(what, str(error))
                if line is not None:
                    self.get_logger().error(f"{what} failed: {line}")
            except RuntimeError:
                self._reraise_unless_stopping()

        return super().create_timer(
            timer_period_sec,
            stop_tolerant if self._local is None else self._local.dispatching(stop_tolerant),
            callback_group=callback_group,
            clock=clock if clock is not None else Clock(clock_type=ClockType.STEADY_TIME),
            autostart=autostart,
        )

    def call_on_spin_thread(self, callback: Callable[[], None]) -> None:
        """Run ``callback`` soon on the thread that spins this node (a thread of its pool, under a
        multi-threaded executor, as any callback would run); callable from any thread (a
        :class:`gldt_ros.runtime.worker.KeepNewestWorker` hands its result back this way). It goes
        through the executor's task queue, which wakes the executor as a message would, and what it
        publishes is delivered as a callback's is. rclpy's events executor crashes the process when
        such a task raises, so an error that is not a stop ends the node through
        :meth:`fail_from_thread` instead. Once the node is being destroyed (:attr:`closing`), a
        result that arrives late (work that outlived its worker's stop) is dropped."""
        if self.closing:
            return
        executor = self.executor
        if executor is None:
            raise RuntimeError(f"{self.get_name()}: call_on_spin_thread on a node no executor spins")

        deliver = callback if self._local is None else self._local.dispatching(callback)

        def run() -> None:
            if self.closing:
                return
            try:
                deliver()
            except BaseException as error:  # noqa: BLE001 - never out of a task (see the docstring)
                self.fail_from_thread(error)

        try:
            executor.create_task(run)
        except Exception:  # noqa: BLE001 - an executor shut down under the caller: nothing left to run it
            if not self.closing and self.context.ok():
                raise

    def fail_from_thread(self, error: BaseException) -> None:
        """End this node's process on an unexpected error raised off the executor's callbacks (a
        worker thread, a posted task), as an error escaping a callback would: logged with its
        traceback, exit status 1, for ``pipeline`` to restart it. A stop in progress (the context
        shut down, or the node being destroyed) is not an error and ends nothing."""
        if self.closing or not self.context.ok():
            return
        import traceback

        trace = "".join(traceback.format_exception(error)).rstrip()
        self.get_logger().fatal(f"{type(error).__name__}: {error}; exiting\n{trace}")
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(1)

    def count_event(self, key: str, count: int = 1) -> None:
        """Add ``count`` events to the counter ``key`` (:data:`PAIRS_SKIPPED`, :data:`STALE_DROPPED`,
        or a node's own): reported in the diagnostics values, WARN in the status after they happened."""
        if count > 0:
            self.events[key] = self.events.get(key, 0) + count

    def set_warning(self, key: str, text: str | None) -> None:
        """Raise (``text``) or clear (``None``) the named WARN condition ``key``: while raised, the
        node's diagnostics status is WARN and its message says ``key: text``. A change goes out
        with the next link check (within :data:`LINK_CHECK_PERIOD_S`, once the node spins, so a
        node raising one in its constructor never reports half its links); raising the same text
        again publishes nothing."""
        if text is None:
            changed = self._warnings.pop(key, None) is not None
        else:
            changed = self._warnings.get(key) != text
            self._warnings[key] = text
        self._status_changed = self._status_changed or changed

    def warnings(self) -> dict[str, str]:
        """The named WARN conditions raised now (:meth:`set_warning`), key -> text."""
        return dict(self._warnings)

    def _reraise_unless_stopping(self) -> None:
        """Called from an ``except RuntimeError``: Ctrl-C shut the context down while a callback
        ran, and its publish failed ("publisher's context is invalid"). That is a stop, not a
        fault; the events executor would log it as FATAL before the node exits, rclpy.spin let it
        pass quietly. With the context still up, the error is real and propagates."""
        if self.context.ok():
            raise

    def warn_throttled(self, key: str, text: str) -> None:
        """Log a warning; repeats of the same ``key`` at most once a second, with their count (a
        fault that lasts, such as a detector that stays away, must not flood the log)."""
        line = self._error_lines.text_for(key, text)
        if line is not None:
            self.get_logger().warning(line)

    def warn_once(self, key: str, text: str) -> None:
        """Log a warning the first time ``key`` is seen (e.g. an unexpected encoding)."""
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    def _publish_if_links_changed(self) -> None:
        if self._status_changed or own_link_counts(self, self._local) != self._reported_links:
            self._publish_diagnostics(regular=False)

    def diagnostics_status(self) -> DiagnosticStatus:
        """This node's status as it would be published now (:meth:`_publish_diagnostics`): OK, or
        WARN with a message naming each reason (inputs ever dropped, skipped pairs or stale drops
        since the last regular status, raised :meth:`set_warning` conditions)."""
        links = own_link_counts(self, self._local)
        rate = 0.0
        if len(self._arrivals) >= 2 and self._arrivals[-1] > self._arrivals[0]:
            rate = (len(self._arrivals) - 1) / (self._arrivals[-1] - self._arrivals[0])
        mean_ms = 1000.0 * sum(self._processing) / len(self._processing) if self._processing else 0.0
        reasons = [f"{self.frames_dropped} input(s) dropped"] if self.frames_dropped else []
        for key, total in self.events.items():
            recent = total - self._events_reported.get(key, 0)
            if recent > 0:
                reasons.append(f"{recent} {_EVENT_TEXT.get(key, key)} ({key}: {total} in all)")
        reasons += [f"{key}: {text}" for key, text in self._warnings.items()]
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN if reasons else DiagnosticStatus.OK,
            name=f"{STATUS_NAME_PREFIX}{self.get_name()}",
            hardware_id=self.get_namespace(),
            message="; ".join(reasons) or "ok",
            values=[
                KeyValue(key="input_rate_hz", value=f"{rate:.2f}"),
                KeyValue(key="processing_time_ms", value=f"{mean_ms:.2f}"),
                KeyValue(key="inputs", value=str(self.frames_in)),
                KeyValue(key="dropped", value=str(self.frames_dropped)),
                # The status is the node's heartbeat: pipeline restarts a process that goes silent.
                KeyValue(key=PID_KEY, value=str(os.getpid())),
                KeyValue(key=PERIOD_KEY, value=f"{float(self.param('diagnostics_period')):g}"),
                *[KeyValue(key=key, value=str(total)) for key, total in self.events.items()],
                *[KeyValue(key=f"warning:{key}", value=text) for key, text in self._warnings.items()],
                *link_key_values(links),
            ],
        )

    def _publish_diagnostics(self, regular: bool = True) -> None:
        """Publish :meth:`diagnostics_status`. A ``regular`` (periodic) status ends the period its
        event counts are judged over; one published because links or warnings changed does not."""
        status = self.diagnostics_status()
        self._reported_links = parse_link_counts(status)
        self._status_changed = False
        if regular:
            self._events_reported = dict(self.events)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(description=spec.description)
    if spec.choices:
        descriptor.additional_constraints = "one of: " + ", ".join(spec.choices)
    if isinstance(spec.default, bool):
        return descriptor
    if spec.minimum is None or spec.maximum is None:  # the schema gives numbers both bounds or neither
        return descriptor
    if isinstance(spec.default, int):
        descriptor.integer_range = [IntegerRange(from_value=int(spec.minimum), to_value=int(spec.maximum), step=1)]
    elif isinstance(spec.default, float):
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(spec.minimum), to_value=float(spec.maximum), step=0.0)
        ]
    return descriptor


def freeze_start_up_objects() -> None:
    """Move every object alive after start-up (modules, models, nodes) out of the garbage
    collector's reach (:func:`gc.freeze`). A full collection otherwise walks all of them, 15-70 ms
    on a small CPU with every thread of the process held meanwhile, and one such pause inside a
    frame shows in the live replay's p99 (docs/experiment-log.md, 2026-12-06). Objects made per
    frame are still collected."""
    gc.collect()
    gc.freeze()


def run_node(node_factory: Callable[[], Node], args: list[str] | None = None, publishes_frames: bool = False) -> int:
    """Standard ``main``: init, spin until Ctrl-C or shutdown, clean up; returns an exit code.

    A node that cannot start (missing model, bad parameter) logs one line and exits with 1. A
    node that ``publishes_frames`` (images, pairs, crops: messages of a MiB or more) swaps the
    graph's shipped DDS profile for its large-segment twin (:mod:`gldt_ros.runtime.dds_profile`). The
    executor is ``$GLDT_EXECUTOR``'s (:mod:`gldt_ros.runtime.executor`; rclpy's events executor by default).
    ``$GLDT_HEAP_TRIM_PERIOD``, which ``pipeline`` sets, hands freed heap pages back to the OS that
    often (:mod:`gldt_ros.runtime.heap_trim`).
    """
    return run_nodes([node_factory], args, publishes_frames)


def run_nodes(
    node_factories: Sequence[Callable[[], Node]], args: list[str] | None = None, publishes_frames: bool = False
) -> int:
    """:func:`run_node` for a process hosting several nodes on one executor
    (:mod:`gldt_ros.runtime.node_group`): they start in order, and one that cannot start stops
    the process with exit 1, as a lone node's would. Several nodes pass their messages to each
    other in-process (:mod:`gldt_ros.runtime.local_delivery`) where the group's DDS profile can be
    used (the shipped profiles are in use) and ``$GLDT_LOCAL_DELIVERY`` is not ``0``."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    try:
        executor = executor_kind()
        start_heap_trimming(trim_period_from_env())
    except ValueError as error:
        print(f"[gldt] cannot start: {error}", flush=True)
        return 1
    uninstall_local_delivery()
    if len(node_factories) > 1 and local_delivery_wanted() and use_group_profile_if_shipped():
        install_local_delivery()
    elif publishes_frames:
        use_frames_profile_if_shipped()
    if executor == EVENTS:
        quiet_sigint_for_events_executor()
    dump_stacks_on_request()
    rclpy.init(args=args)
    nodes: list[Node] = []
    try:
        for factory in node_factories:
            nodes.append(factory())
        freeze_start_up_objects()
        for node in nodes:
            print(f"[gldt] {node.get_name()} ready", flush=True)
        spin_nodes(nodes, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, FileNotFoundError) as error:
        if len(nodes) == len(node_factories):
            raise  # callbacks are guarded; anything else escaping spin is a bug worth a traceback
        print(f"[gldt] cannot start: {error}", flush=True)
        return 1
    except RuntimeError:
        # SIGINT shuts the context down while the executor may be inside take_message, which
        # then fails to convert the half-taken message; that is a stop, not a crash.
        if rclpy.ok():
            raise
    finally:
        limit_teardown()  # rclpy's destroy_node can hang; the node's work is done by now
        for node in nodes:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
