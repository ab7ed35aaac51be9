"""What every GL-DT node shares: schema-declared parameters, diagnostics, one-line errors.

Each node processes messages in callbacks; a bad message must cost one log line and that message
only, never the node. :meth:`GldtNode.guarded` wraps a callback so that documented errors
(``ValueError`` and its subclasses such as ``ImageDecodeError``) are counted as dropped frames in
the node's ``/diagnostics`` status and logged in one line, repeats of the same kind at most once a
second (:mod:`gldt_ros.runtime.log_throttle`).

The diagnostics also carry how many peers each of the node's topics has matched
(:mod:`gldt_ros.interface.graph_links`), republished as soon as that changes: it is how the
``pipeline`` command knows the graph is connected end to end before it sends the first frame.

:func:`run_node` is every node's ``main``: it applies the process-wide runtime settings of this
package (executor, heap trimming, DDS profile, stack dumps, bounded teardown) and spins the node.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from gldt_ros.interface import qos, topics
from gldt_ros.interface.graph_links import link_key_values, own_link_counts
from gldt_ros.interface.params import SCHEMA, ParamSpec
from gldt_ros.runtime.dds_profile import use_frames_profile_if_shipped
from gldt_ros.runtime.executor import EVENTS, executor_kind, quiet_sigint_for_events_executor, spin_node
from gldt_ros.runtime.heap_trim import start_heap_trimming, trim_period_from_env
from gldt_ros.runtime.log_throttle import LogThrottle
from gldt_ros.runtime.stack_dump import dump_stacks_on_request
from gldt_ros.runtime.teardown_limit import limit_teardown

#: How often a node checks whether its matched peers changed (a cheap count per topic).
LINK_CHECK_PERIOD_S = 0.1
#: A node's ``/diagnostics`` status is named this prefix plus the node name.
STATUS_NAME_PREFIX = "gldt/"


class GldtNode(Node):
    """Base class: declares the node's parameters from :data:`SCHEMA` and reports diagnostics."""

    def __init__(self, name: str, **kwargs: Any) -> None:
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
                line = self._error_lines.text_for(what, str(error))
                if line is not None:
                    self.get_logger().error(f"dropped {what}: {line}")
            except RuntimeError:
                self._reraise_unless_stopping()
            finally:
                self._processing.append(time.perf_counter() - start)

        return wrapper

    def create_timer(self, timer_period_sec: float, callback: Callable[[], None], *args: Any, **kwargs: Any) -> Any:
        """``Node.create_timer`` whose callback may be cut short by a stop, as :meth:`guarded`'s
        may: every timer of the graph's nodes publishes (diagnostics, links, report timeouts)."""

        def stop_tolerant() -> None:
            try:
                callback()
            except RuntimeError:
                self._reraise_unless_stopping()

        return super().create_timer(timer_period_sec, stop_tolerant, *args, **kwargs)

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
        if own_link_counts(self) != self._reported_links:
            self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        links = own_link_counts(self)
        self._reported_links = links
        rate = 0.0
        if len(self._arrivals) >= 2 and self._arrivals[-1] > self._arrivals[0]:
            rate = (len(self._arrivals) - 1) / (self._arrivals[-1] - self._arrivals[0])
        mean_ms = 1000.0 * sum(self._processing) / len(self._processing) if self._processing else 0.0
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK if self.frames_dropped == 0 else DiagnosticStatus.WARN,
            name=f"{STATUS_NAME_PREFIX}{self.get_name()}",
            hardware_id=self.get_namespace(),
            message="ok" if self.frames_dropped == 0 else f"{self.frames_dropped} input(s) dropped",
            values=[
                KeyValue(key="input_rate_hz", value=f"{rate:.2f}"),
                KeyValue(key="processing_time_ms", value=f"{mean_ms:.2f}"),
                KeyValue(key="inputs", value=str(self.frames_in)),
                KeyValue(key="dropped", value=str(self.frames_dropped)),
                *link_key_values(links),
            ],
        )
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


def run_node(node_factory: Callable[[], Node], args: list[str] | None = None, publishes_frames: bool = False) -> int:
    """Standard ``main``: init, spin until Ctrl-C or shutdown, clean up; returns an exit code.

    A node that cannot start (missing model, bad parameter) logs one line and exits with 1. A
    node that ``publishes_frames`` (images, pairs, crops: messages of a MiB or more) swaps the
    graph's shipped DDS profile for its large-segment twin (:mod:`gldt_ros.runtime.dds_profile`). The
    executor is ``$GLDT_EXECUTOR``'s (:mod:`gldt_ros.runtime.executor`; rclpy's events executor by default).
    ``$GLDT_HEAP_TRIM_PERIOD``, which ``pipeline`` sets, hands freed heap pages back to the OS that
    often (:mod:`gldt_ros.runtime.heap_trim`).
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException

    try:
        executor = executor_kind()
        start_heap_trimming(trim_period_from_env())
    except ValueError as error:
        print(f"[gldt] cannot start: {error}", flush=True)
        return 1
    if publishes_frames:
        use_frames_profile_if_shipped()
    if executor == EVENTS:
        quiet_sigint_for_events_executor()
    dump_stacks_on_request()
    rclpy.init(args=args)
    node = None
    try:
        node = node_factory()
        print(f"[gldt] {node.get_name()} ready", flush=True)
        spin_node(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ValueError, FileNotFoundError) as error:
        if node is not None:
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
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
