"""Whether the graph's data paths are connected, not just whether its nodes exist.

DDS discovery is pairwise: a reliable publisher delivers only to subscriptions *it* has matched,
and a subscription accepts only publishers *it* has matched. That a node name, or even a
subscription, is visible to one process says nothing about whether two *other* processes have
found each other yet, so a frame sent right after start-up can vanish between two nodes.

Each GL-DT node therefore reports, in its ``/diagnostics`` status, how many peers each of its
topics has matched (:func:`own_link_counts`, :func:`link_key_values`; written by
:class:`gldt_ros.runtime.node_base.GldtNode`). A process that knows the graph (the ``pipeline``
command's driver, :class:`gldt_ros.launcher.replay.GraphDriver`) compares those reports with what
it sees itself (:func:`missing_links`): every endpoint it can see on a topic must also be matched
by each node on that topic. Nodes report facts; only the driver, which started the graph, judges
them. Both sides read the report's format from here, which is why it is part of the interface.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, Protocol

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node

#: Key prefixes in a node's diagnostics: matched subscriptions of one of its publishers, and
#: matched publishers of one of its subscriptions; the fully qualified topic name follows.
MATCHED_SUBSCRIPTIONS = "matched_subscriptions:"
MATCHED_PUBLISHERS = "matched_publishers:"

#: Endpoints every node has that carry none of the graph's data.
_INFRASTRUCTURE_TOPICS = ("/rosout", "/parameter_events", "/diagnostics")


class EndpointCounts(Protocol):
    """The graph queries :func:`missing_links` makes of the observing process (an rclpy ``Node``'s)."""

    def count_subscribers(self, topic_name: str, /) -> int: ...

    def count_publishers(self, topic_name: str, /) -> int: ...


class EndpointOwners(Protocol):
    """The graph queries :func:`node_endpoint_gids` makes of the observing process (an rclpy
    ``Node``'s); each endpoint info has ``node_name``, ``node_namespace`` and ``endpoint_gid``."""

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]: ...

    def get_publishers_info_by_topic(self, topic_name: str, /) -> Sequence[Any]: ...

    def get_subscriptions_info_by_topic(self, topic_name: str, /) -> Sequence[Any]: ...


class LocalPeers(Protocol):
    """The endpoints of the node's own process that DDS does not match with it, because that
    process's messages between its nodes do not go through DDS
    (:class:`gldt_ros.runtime.local_delivery.LocalDelivery`)."""

    def subscriber_count(self, topic: str, /) -> int: ...

    def publisher_count(self, topic: str, /) -> int: ...


def own_link_counts(node: Node, local: LocalPeers | None = None) -> dict[str, int]:
    """For each of ``node``'s data topics, how many peers it is linked with so far: matched by DDS,
    plus, with ``local``, the endpoints of its own process that DDS leaves to ``local``."""
    counts: dict[str, int] = {}
    for publisher in node.publishers:
        topic = publisher.topic_name
        if topic not in _INFRASTRUCTURE_TOPICS:
            own = local.subscriber_count(topic) if local is not None else 0
            counts[MATCHED_SUBSCRIPTIONS + topic] = publisher.get_subscription_count() + own
    for subscription in node.subscriptions:
        topic = subscription.topic_name
        if topic not in _INFRASTRUCTURE_TOPICS:
            own = local.publisher_count(topic) if local is not None else 0
            counts[MATCHED_PUBLISHERS + topic] = subscription.get_publisher_count() + own
    return counts


def link_key_values(counts: dict[str, int]) -> list[KeyValue]:
    """The counts as diagnostics key/values (sorted, so equal counts give equal messages)."""
    return [KeyValue(key=key, value=str(value)) for key, value in sorted(counts.items())]


def parse_link_counts(status: DiagnosticStatus) -> dict[str, int]:
    """The link counts a node put in its diagnostics status (empty for other statuses)."""
    counts: dict[str, int] = {}
    for pair in status.values:
        if pair.key.startswith((MATCHED_SUBSCRIPTIONS, MATCHED_PUBLISHERS)):
            try:
                counts[pair.key] = int(pair.value)
            except ValueError:
                continue  # not ours to judge: a foreign status using the same key
    return counts


def missing_links(observer: EndpointCounts, reports: dict[str, dict[str, int]]) -> list[str]:
    """Links not yet matched, one readable line each; empty once the graph is connected.

    ``reports`` maps a node name to its :func:`own_link_counts`. Each count is compared with the
    number of endpoints ``observer`` sees on that topic: a publisher must have matched every
    subscription the observer knows of, a subscription every publisher.
    """
    missing: list[str] = []
    for node_name, counts in sorted(reports.items()):
        for key, matched in sorted(counts.items()):
            if key.startswith(MATCHED_SUBSCRIPTIONS):
                topic = key[len(MATCHED_SUBSCRIPTIONS) :]
                seen = observer.count_subscribers(topic)
                role = "subscriptions"
            else:
                topic = key[len(MATCHED_PUBLISHERS) :]
                seen = observer.count_publishers(topic)
                role = "publishers"
            if matched < seen:
                missing.append(f"{node_name}: {topic} matched {matched} of {seen} {role}")
    return missing


#: The node name rmw reports for an endpoint whose process has not yet told this one which node
#: owns it: ``ros_discovery_info`` arrives after the endpoint itself, sooner with the graph's Fast
#: DDS profile (``config/fastdds_profile.xml`` says why) than with Fast DDS's defaults.
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"


def node_endpoint_gids(
    observer: EndpointOwners,
    node_name: str,
    namespace: str,
    topics: Iterable[str] | None = None,
    include_unnamed: bool = False,
) -> dict[str, set[bytes]]:
    """For each data topic of the node ``namespace/node_name``, the ids of its endpoints that
    ``observer`` can see: a restarted process is told apart from the dead one by new ids (a killed
    process stays visible until its DDS lease runs out).

    ``topics`` limits the search to those topics (cheaper than listing the whole graph when
    polling). ``include_unnamed`` also counts endpoints whose owner is not known yet: DDS has
    matched them, so data can already flow, while the graph API still waits for the owner's name.
    """
    gids: dict[str, set[bytes]] = {}
    names = [topic for topic, _ in observer.get_topic_names_and_types()] if topics is None else list(topics)
    for info_by_topic in (observer.get_publishers_info_by_topic, observer.get_subscriptions_info_by_topic):
        for topic in names:
            if topic in _INFRASTRUCTURE_TOPICS:
                continue
            for info in info_by_topic(topic):
                named = info.node_name == node_name and info.node_namespace.rstrip("/") == namespace.rstrip("/")
                if named or (include_unnamed and info.node_name == UNKNOWN_NODE_NAME):
                    gids.setdefault(topic, set()).add(bytes(info.endpoint_gid))
    return gids


class LiveEndpoints:
    """The endpoint counts ``observer`` sees, less the endpoints ``dead``: those of a process that
    was killed stay visible until its DDS lease runs out (5 s with the shipped profile), and no
    node can match them, so a relink judged against them would wait out the lease."""

    def __init__(self, observer: EndpointOwners, dead: set[bytes]) -> None:
        self.observer, self.dead = observer, dead

    def count_publishers(self, topic_name: str, /) -> int:
        infos = self.observer.get_publishers_info_by_topic(topic_name)
        return sum(bytes(info.endpoint_gid) not in self.dead for info in infos)

    def count_subscribers(self, topic_name: str, /) -> int:
        infos = self.observer.get_subscriptions_info_by_topic(topic_name)
        return sum(bytes(info.endpoint_gid) not in self.dead for info in infos)


def reporting_nodes_missing(expected: Iterable[str], reports: dict[str, dict[str, int]]) -> list[str]:
    """Expected node names that have not reported link counts yet."""
    return sorted(name for name in expected if name not in reports)
