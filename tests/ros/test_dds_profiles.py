"""The large-segment Fast DDS profile: the shipped profile's twin, given only to the processes
that publish frames, and what a frame pair needs."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from gldt_ros.runtime.dds_profile import (  # noqa: E402
    DDS_PROFILE_VARIABLE,
    profile_for_children,
    shipped_frames_profile,
    shipped_group_profile,
    shipped_profile,
    use_frames_profile_if_shipped,
    use_group_profile_if_shipped,
)
from support import isolated_ros_env  # noqa: E402

NAMESPACE = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"
#: The largest frame pair of the graph: two letterboxed 640x512 BGR images (the real clips).
LARGEST_PAIR_BYTES = 2 * 640 * 512 * 3
SEGMENT_SETTINGS = {f"{NAMESPACE}segment_size", f"{NAMESPACE}maxMessageSize"}


def _tree_without(path: Path, tags: set[str]) -> list[tuple[str, str]]:
    """Every element as (tag, text) in document order, leaving out ``tags``."""
    root = ElementTree.parse(path).getroot()
    return [(element.tag, (element.text or "").strip()) for element in root.iter() if element.tag not in tags]


def _shm_setting(path: Path, tag: str) -> int | None:
    for descriptor in ElementTree.parse(path).getroot().iter(f"{NAMESPACE}transport_descriptor"):
        if descriptor.findtext(f"{NAMESPACE}type") == "SHM":
            value = descriptor.findtext(f"{NAMESPACE}{tag}")
            return None if value is None else int(value)
    raise AssertionError(f"{path} has no SHM transport descriptor")


def test_frames_profile_differs_from_the_shipped_one_only_in_the_segment() -> None:
    """Every other setting (discovery, heartbeats, health check) must stay the same in both, or a
    restarted frame_pair_buffer would rejoin the graph unlike the other nodes."""
    assert _tree_without(shipped_frames_profile(), SEGMENT_SETTINGS) == _tree_without(
        shipped_profile(), SEGMENT_SETTINGS
    )
    assert _shm_setting(shipped_profile(), "segment_size") is None, (
        "the small-message nodes keep Fast DDS's 512 KiB segment"
    )


IGNORE_LOCAL = "fastdds.ignore_local_endpoints"
PROPERTY_TAGS = {f"{NAMESPACE}{tag}" for tag in ("propertiesPolicy", "properties", "property", "name", "value")}


def _properties(path: Path) -> dict[str, str]:
    return {
        (element.findtext(f"{NAMESPACE}name") or "").strip(): (element.findtext(f"{NAMESPACE}value") or "").strip()
        for element in ElementTree.parse(path).getroot().iter(f"{NAMESPACE}property")
    }


def test_group_profile_is_the_frames_profile_that_ignores_its_own_endpoints() -> None:
    """A group's process holds frame_pair_buffer (large segment) and passes messages between its
    nodes in-process (gldt_ros.runtime.local_delivery), so DDS must not also match them."""
    assert _properties(shipped_group_profile()) == {IGNORE_LOCAL: "true"}
    assert _properties(shipped_frames_profile()) == {} and _properties(shipped_profile()) == {}
    assert _tree_without(shipped_group_profile(), PROPERTY_TAGS) == _tree_without(
        shipped_frames_profile(), PROPERTY_TAGS
    )


def test_only_a_shipped_profile_is_swapped_for_the_group_profile(monkeypatch) -> None:
    for shipped in (shipped_profile(), shipped_frames_profile()):
        monkeypatch.setenv(DDS_PROFILE_VARIABLE, str(shipped))
        assert use_group_profile_if_shipped() is True
        assert os.environ[DDS_PROFILE_VARIABLE] == str(shipped_group_profile())
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, "/etc/my_profile.xml")
    assert use_group_profile_if_shipped() is False, "a profile the user exported wins, DDS links the group"
    assert os.environ[DDS_PROFILE_VARIABLE] == "/etc/my_profile.xml"
    monkeypatch.delenv(DDS_PROFILE_VARIABLE)
    assert use_group_profile_if_shipped() is False and DDS_PROFILE_VARIABLE not in os.environ
    group = {DDS_PROFILE_VARIABLE: str(shipped_group_profile())}
    assert profile_for_children(group) == {DDS_PROFILE_VARIABLE: str(shipped_profile())}


def test_frames_profile_carries_the_largest_frame_pair_in_one_message() -> None:
    segment = _shm_setting(shipped_frames_profile(), "segment_size")
    largest = _shm_setting(shipped_frames_profile(), "maxMessageSize")
    assert segment is not None and largest is not None
    assert largest >= LARGEST_PAIR_BYTES + 4096, "a 640x512 pair (and its header) must not be fragmented"
    assert segment >= 2 * largest, (
        "room for two pairs in flight at once (the writer keeps PAIRS_KEPT = 2 for resending)"
    )


def test_only_the_shipped_profile_is_swapped_for_its_frames_twin(monkeypatch) -> None:
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, str(shipped_profile()))
    assert use_frames_profile_if_shipped() == str(shipped_frames_profile())
    assert os.environ[DDS_PROFILE_VARIABLE] == str(shipped_frames_profile())
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, "/etc/my_profile.xml")
    assert use_frames_profile_if_shipped() == "/etc/my_profile.xml", "a profile the user exported wins"
    monkeypatch.delenv(DDS_PROFILE_VARIABLE)
    assert use_frames_profile_if_shipped() == "" and DDS_PROFILE_VARIABLE not in os.environ, (
        "a node started by hand keeps Fast DDS's defaults"
    )


def test_children_of_a_frames_process_start_on_the_small_segment_profile(monkeypatch) -> None:
    """The pipeline switches to the frames twin for itself; the nodes it starts must not inherit
    it (the segment is real memory), and a user's profile passes through untouched."""
    from gldt_ros.launcher.pipeline import node_environment

    monkeypatch.setenv(DDS_PROFILE_VARIABLE, str(shipped_profile()))
    use_frames_profile_if_shipped()
    assert node_environment(tune_malloc=False)[DDS_PROFILE_VARIABLE] == str(shipped_profile())
    assert profile_for_children({DDS_PROFILE_VARIABLE: "/etc/my.xml"}) == {DDS_PROFILE_VARIABLE: "/etc/my.xml"}
    assert profile_for_children({}) == {}


def test_frame_pair_buffer_asks_for_the_frames_profile_and_the_detectors_do_not(monkeypatch) -> None:
    import importlib

    from gldt_ros.interface.graph import NODES

    asked: dict[str, bool] = {}
    for name, module_name in NODES.items():
        module = importlib.import_module(module_name)
        monkeypatch.setattr(
            module,
            "run_node",
            lambda factory, publishes_frames=False, _n=name: asked.setdefault(_n, publishes_frames) and 0,
        )
        module.main()
    assert asked == {name: name == "frame_pair_buffer" for name in NODES}


SEGMENT_PROBE = (
    "import sys, rclpy; rclpy.init(); node = rclpy.create_node('segment_probe'); "
    "print('up', flush=True); sys.stdin.readline(); node.destroy_node(); rclpy.shutdown()"
)


def _mapped_segments(pid: int) -> dict[str, int]:
    """Fast DDS participant segments (``/dev/shm/fastrtps_<guid>``, not ports or locks) that
    process ``pid`` has mapped, with their sizes."""
    paths = {
        line.split()[-1] for line in Path(f"/proc/{pid}/maps").read_text().splitlines() if "/dev/shm/fastrtps_" in line
    }
    segments = [Path(p) for p in paths if not Path(p).name.startswith("fastrtps_port") and not p.endswith("_el")]
    return {p.name: p.stat().st_size for p in segments if p.is_file()}


@pytest.mark.skipif(not Path("/proc/self/maps").is_file(), reason="reads the probe's memory map from /proc (Linux)")
@pytest.mark.parametrize("frames", [False, True])
def test_a_participant_on_the_frames_profile_gets_the_large_segment(frames: bool) -> None:
    """The segment size must reach Fast DDS, not just parse: a participant started on each
    profile opens a segment of the size the file asks for (Fast DDS adds a little for its own
    bookkeeping), and the small-message profile keeps Fast DDS's 512 KiB."""
    import subprocess
    import sys

    env = isolated_ros_env()
    env[DDS_PROFILE_VARIABLE] = str(shipped_frames_profile() if frames else shipped_profile())
    probe = subprocess.Popen(
        [sys.executable, "-c", SEGMENT_PROBE], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert probe.stdout is not None and probe.stdout.readline().strip() == "up"
        new = _mapped_segments(probe.pid)
    finally:
        probe.communicate("\n", timeout=30)
    assert new, "the probe mapped no Fast DDS segment: is the shared-memory transport off?"
    size = max(new.values())  # its own; Fast DDS may also map a small one for other purposes
    wanted = _shm_setting(shipped_frames_profile(), "segment_size") if frames else 512 * 1024
    assert wanted is not None, "the frames profile sets no segment_size"
    assert wanted <= size < 1.2 * wanted, f"segment of {size} bytes for a profile asking {wanted}"
