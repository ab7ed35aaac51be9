"""Messages between the nodes of one process, handed over as Python objects instead of DDS samples.

A process that hosts several of the graph's nodes (:mod:`gldt_ros.runtime.node_group`) passes a
LOCAL frame along five hops inside itself: tick, predictions, decision, ROI crops, detections.
Over DDS each of them converts the message to C, serialises it, wakes the executor, and converts
it back to Python, although writer and reader share an interpreter; ``python -m
gldt_ros.bench.hops`` finds that about as expensive as the work the nodes do on the frame.

In such a process the participant is told not to match its own endpoints (the Fast DDS property
``fastdds.ignore_local_endpoints`` of ``config/fastdds_profile_group.xml``), and a
:class:`LocalDelivery` hands each message published by one of its nodes to the process's own
subscriptions on that topic. DDS still carries the message to every other process: a publisher
writes to DDS whenever a reader elsewhere has matched it (a recorder, ``ros2 topic echo``, a
detector in its own process), and always where its durability keeps samples for late joiners.

What a node sees does not change:

* every subscription of the topic and type in the process gets the message, in publication
  order, the publishing node's own subscriptions included, as DDS delivers them;
* a message is handled after the callback that published it has returned, never inside it, as
  an executor would: callbacks do not nest, and a node never sees its own state half-updated;
* the receiver gets the publisher's object, not a copy, so neither may change a message after
  publishing or receiving it (the graph's nodes build a new message for every publication);
* the node's link counts (:func:`gldt_ros.interface.graph_links.own_link_counts`) count the
  process's own peers, which DDS no longer matches, so ``pipeline`` still sees the graph linked.

A process uses one delivery, from the thread that spins its executor (nodes are created and
spun on the same thread); a publication from another thread is a programming error and raises.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

#: Environment variable that turns local delivery off in a process that would use it ("0"), for
#: A/B runs of the graph; anything else, or unset, leaves it on.
LOCAL_DELIVERY_ENV = "GLDT_LOCAL_DELIVERY"


@dataclass(frozen=True)
class _Subscriber:
    owner: object
    message_type: type
    callback: Callable[[Any], None]


class LocalDelivery:
    """The in-process message switch of one process (module docstring)."""

    def __init__(self) -> None:
        self._subscribers: dict[str, list[_Subscriber]] = {}
        self._publishers: dict[str, dict[int, object]] = {}  # topic -> id(publisher) -> its owner
        self._queue: deque[tuple[Callable[[Any], None], Any]] = deque()
        self._depth = 0  # callbacks running now (executor or local), outermost first
        self._draining = False
        self._thread = threading.get_ident()
        self.delivered = 0

    # ---------------------------------------------------------------- registration
    def add_subscriber(self, topic: str, message_type: type, callback: Callable[[Any], None], owner: object) -> None:
        """Hand messages published in this process on ``topic`` (fully qualified) with type
        ``message_type`` to ``callback``."""
        self._subscribers.setdefault(topic, []).append(_Subscriber(owner, message_type, callback))

    def add_publisher(self, topic: str, publisher: object, owner: object) -> None:
        """Count ``publisher`` (of ``owner``) among the process's writers on ``topic``."""
        self._publishers.setdefault(topic, {})[id(publisher)] = owner

    def forget(self, owner: object) -> None:
        """Drop every subscriber and publisher ``owner`` (a node being destroyed) registered."""
        for topic, subscribers in list(self._subscribers.items()):
            kept = [subscriber for subscriber in subscribers if subscriber.owner is not owner]
            self._subscribers[topic] = kept
        for publishers in self._publishers.values():
            for key in [key for key, publisher_owner in publishers.items() if publisher_owner is owner]:
                del publishers[key]

    def subscriber_count(self, topic: str) -> int:
        """Subscriptions of this process on ``topic``."""
        return len(self._subscribers.get(topic, ()))

    def publisher_count(self, topic: str) -> int:
        """Publishers of this process on ``topic``."""
        return len(self._publishers.get(topic, ()))

    # ---------------------------------------------------------------- delivery
    def publish(self, topic: str, message: Any) -> None:
        """Queue ``message`` for every subscriber of ``topic`` with its type; delivered once the
        running callback returns, or at once when no callback is running."""
        self._check_thread()
        for subscriber in self._subscribers.get(topic, ()):
            if type(message) is subscriber.message_type:
                self._queue.append((subscriber.callback, message))
        if self._depth == 0:
            self._drain()

    def dispatching(self, callback: Callable[..., Any]) -> Callable[..., Any]:
        """``callback`` (one the executor runs: a subscription's or a timer's) wrapped so that what
        it publishes locally is delivered after it returns."""

        def run_then_deliver(*args: Any) -> Any:
            self._depth += 1
            try:
                return callback(*args)
            finally:
                self._depth -= 1
                if self._depth == 0 and self._queue:
                    self._drain()

        return run_then_deliver

    def _drain(self) -> None:
        if self._draining:
            return  # the loop below, further up this thread's stack, delivers it
        self._draining = True
        try:
            while self._queue:
                callback, message = self._queue.popleft()
                self._depth += 1
                try:
                    callback(message)
                finally:
                    self._depth -= 1
                self.delivered += 1
        finally:
            self._draining = False

    def _check_thread(self) -> None:
        if threading.get_ident() != self._thread:
            raise RuntimeError(
                "local delivery: a message was published from a thread other than the one that spins "
                "this process's nodes"
            )


class LocalPublisher:
    """An rclpy publisher whose messages reach this process's subscriptions through a
    :class:`LocalDelivery` and other processes through DDS (module docstring). Everything but
    :meth:`publish` and :meth:`get_subscription_count` is the wrapped publisher's."""

    def __init__(self, publisher: Any, delivery: LocalDelivery) -> None:
        from rclpy.qos import DurabilityPolicy

        self._publisher = publisher
        self._delivery = delivery
        self._topic = str(publisher.topic_name)
        self._keeps_samples = publisher.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL

    def publish(self, message: Any) -> None:
        # A writer that keeps samples for late joiners writes even when no one listens yet.
        if self._keeps_samples or self._publisher.get_subscription_count() > 0:
            self._publisher.publish(message)
        self._delivery.publish(self._topic, message)

    def get_subscription_count(self) -> int:
        """Subscriptions this publisher reaches: matched by DDS in other processes, and this
        process's own."""
        return int(self._publisher.get_subscription_count()) + self._delivery.subscriber_count(self._topic)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._publisher, name)


_ACTIVE: LocalDelivery | None = None


def local_delivery_wanted(environ: Mapping[str, str] | None = None) -> bool:
    """Whether ``$GLDT_LOCAL_DELIVERY`` leaves local delivery on (anything but ``0``)."""
    environ = os.environ if environ is None else environ
    return environ.get(LOCAL_DELIVERY_ENV, "").strip() != "0"


def install_local_delivery() -> LocalDelivery:
    """Make a new :class:`LocalDelivery` the one the nodes created in this process from now on
    use (:class:`gldt_ros.runtime.node_base.GldtNode`). Only where DDS does not match the
    process's own endpoints (module docstring): otherwise every message would arrive twice."""
    global _ACTIVE
    _ACTIVE = LocalDelivery()
    return _ACTIVE


def uninstall_local_delivery() -> None:
    """Nodes created from now on use DDS alone."""
    global _ACTIVE
    _ACTIVE = None


def active_local_delivery() -> LocalDelivery | None:
    """The process's :class:`LocalDelivery`, if :func:`install_local_delivery` made one."""
    return _ACTIVE
