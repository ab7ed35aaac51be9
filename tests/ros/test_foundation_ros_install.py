"""The colcon install tree is complete, and ``pipeline`` starts its graph and stops cleanly."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from gldt_ros.interface.graph import NODES
from support import REPO_ROOT, isolated_ros_env

yaml = pytest.importorskip("yaml")

INSTALL = REPO_ROOT / "install" / "gldt_ros"
#: One per graph node, plus the ``pipeline`` command and the example subscriber.
EXECUTABLES = (*NODES, "threat_monitor", "pipeline")


@pytest.mark.parametrize("name", EXECUTABLES)
def test_install_tree_has_executable(name: str) -> None:
    path = INSTALL / "lib" / "gldt_ros" / name
    assert path.is_file(), f"{path} missing: `ros2 run gldt_ros {name}` would fail"
    assert os.access(path, os.X_OK), f"{path} is not executable"


@pytest.mark.parametrize("name", NODES)
def test_each_graph_node_is_a_module_that_builds_and_runs_it(name: str) -> None:
    """What ``pipeline --in-process``, the warm spare and each executable call on a node's module."""
    import importlib

    module = importlib.import_module(NODES[name])
    assert callable(module.create_node) and callable(module.main)


def test_install_tree_has_share_files() -> None:
    share = INSTALL / "share" / "gldt_ros"
    for relative in (
        "package.xml",
        "config/gldt.yaml",
        "config/fastdds_profile.xml",
        "config/fastdds_profile_frames.xml",
        "launch/gldt.launch.py",
    ):
        assert (share / relative).is_file(), f"share/gldt_ros/{relative} missing"
    assert (
        REPO_ROOT / "install" / "gldt_ros" / "share" / "ament_index" / "resource_index" / "packages" / "gldt_ros"
    ).is_file()


def test_pipeline_points_fast_dds_at_the_shipped_profile_unless_the_user_chose_one(monkeypatch) -> None:
    """The profile that makes a restarted node discoverable in 250 ms, not 3 s, and resends what a
    late joiner missed within 100 ms, is the default; a profile the user exported is left alone."""
    import xml.etree.ElementTree as ElementTree

    from gldt_ros.runtime.dds_profile import DDS_PROFILE_VARIABLE, use_graph_dds_profile

    monkeypatch.delenv(DDS_PROFILE_VARIABLE, raising=False)
    profile = Path(use_graph_dds_profile())
    assert os.environ[DDS_PROFILE_VARIABLE] == str(profile)
    assert profile.parent == INSTALL / "share" / "gldt_ros" / "config", profile
    namespace = {"dds": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    period = ElementTree.parse(profile).find(".//dds:leaseAnnouncement/dds:nanosec", namespace)
    assert period is not None and period.text is not None and int(period.text) <= 250_000_000
    heartbeat = ElementTree.parse(profile).find(
        ".//dds:data_writer/dds:times/dds:heartbeatPeriod/dds:nanosec", namespace
    )
    assert heartbeat is not None and heartbeat.text is not None and int(heartbeat.text) <= 100_000_000, (
        "late joiners must not wait 3 s for a lost sample"
    )
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, "/etc/my_profile.xml")
    assert use_graph_dds_profile() == "/etc/my_profile.xml"


PARTICIPANT_PROBE = (
    "import rclpy; rclpy.init(); rclpy.create_node('profile_probe').destroy_node(); rclpy.shutdown(); print('up')"
)


@pytest.mark.parametrize("profile_name", ["fastdds_profile.xml", "fastdds_profile_frames.xml"])
def test_fast_dds_loads_the_shipped_profile_without_a_parser_error(tmp_path: Path, profile_name: str) -> None:
    """Fast DDS falls back to its defaults on a profile it cannot parse, logging an error and
    nothing else: a typo would silently undo every setting above. A participant started with a
    shipped profile must log no XMLPARSER error; the same profile with one element misspelt must,
    which shows the probe can fail."""
    import sys

    shipped = INSTALL / "share" / "gldt_ros" / "config" / profile_name
    misspelt = tmp_path / "misspelt.xml"
    misspelt.write_text(shipped.read_text().replace("healthy_check_timeout_ms>", "healthy_check_timeout>"))
    outputs = {}
    for profile in (shipped, misspelt):
        env = isolated_ros_env()
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
        result = subprocess.run(
            [sys.executable, "-c", PARTICIPANT_PROBE],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=60,
        )
        assert result.returncode == 0 and result.stdout.rstrip().endswith("up"), result.stdout
        outputs[profile] = result.stdout  # Fast DDS logs its errors to stdout
    assert "XMLPARSER" not in outputs[shipped], outputs[shipped]
    assert "XMLPARSER" in outputs[misspelt] and "healthy_check_timeout" in outputs[misspelt]


def test_node_processes_get_the_memory_settings_unless_the_user_set_them_or_opted_out(monkeypatch) -> None:
    from gldt_ros.launcher.pipeline import NODE_MALLOC_SETTINGS, node_environment, parse_args
    from gldt_ros.runtime.heap_trim import HEAP_TRIM_PERIOD_ENV

    for key in NODE_MALLOC_SETTINGS:
        monkeypatch.delenv(key, raising=False)
    assert parse_args([]).tune_malloc and not parse_args(["--default-malloc"]).tune_malloc
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    tuned = node_environment(tune_malloc=True)
    assert all(tuned[key] == value for key, value in NODE_MALLOC_SETTINGS.items())
    assert float(tuned[HEAP_TRIM_PERIOD_ENV]) > 0, "the nodes trim their heaps"
    assert "MALLOC_MMAP_THRESHOLD_" not in tuned, "a fixed mmap threshold makes every frame buffer fault its pages in"
    assert not set(NODE_MALLOC_SETTINGS) & set(node_environment(tune_malloc=False))
    monkeypatch.setenv("MALLOC_ARENA_MAX", "8")
    assert node_environment(tune_malloc=True)["MALLOC_ARENA_MAX"] == "8", "a value the user exported wins"


def test_config_matches_parameter_schema() -> None:
    from gldt_ros.interface.params import SCHEMA

    config = yaml.safe_load((REPO_ROOT / "src" / "gldt_ros" / "config" / "gldt.yaml").read_text())
    for key, section in config.items():
        node = key.rsplit("/", 1)[-1]
        assert node in SCHEMA, f"config section {key} names no node of the schema"
        specs = {spec.name: spec for spec in SCHEMA[node]}
        for name, value in section["ros__parameters"].items():
            assert name in specs, f"{key}.{name} is not a declared parameter"
            specs[name].validate(value)
            assert type(value) is type(specs[name].default), f"{key}.{name} has the wrong type"


def test_shipped_config_holds_the_schema_defaults() -> None:
    from gldt_ros.interface.params import default_yaml

    shipped = (REPO_ROOT / "src" / "gldt_ros" / "config" / "gldt.yaml").read_text()
    assert shipped == default_yaml(), "config/gldt.yaml is stale: run `make docs`"


def test_parameter_page_is_generated_from_schema() -> None:
    from gldt_ros.interface.params import markdown_table

    page = (REPO_ROOT / "docs" / "parameters.md").read_text()
    assert markdown_table() in page, "docs/parameters.md is stale: run `make docs`"


def test_pipeline_starts_and_stops_cleanly() -> None:
    pipeline = INSTALL / "lib" / "gldt_ros" / "pipeline"
    process = subprocess.Popen(
        [str(pipeline)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        env=isolated_ros_env(),
    )
    lines: list[str] = []
    try:
        deadline = time.monotonic() + 120
        assert process.stdout is not None
        while time.monotonic() < deadline:
            line = process.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "nodes up" in line:
                break
        assert any("nodes up" in line for line in lines), "pipeline never reported its nodes up:\n" + "".join(lines)
        os.killpg(process.pid, signal.SIGINT)
        output, _ = process.communicate(timeout=60)
        lines.append(output)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    text = "".join(lines)
    assert process.returncode == 0, f"pipeline exited with {process.returncode}:\n{text}"
    assert "Traceback" not in text, text


def test_the_detector_nodes_ask_the_model_about_their_classes_parameter() -> None:
    from gldt_ros.interface.params import detector_kwargs

    params = {
        "model_path": "",
        "providers": "CPUExecutionProvider",
        "num_threads": 1,
        "score_threshold": 0.1,
        "classes": "1",
    }
    assert detector_kwargs(params.get)["classes"] == (1,)
    assert detector_kwargs({**params, "classes": ""}.get)["classes"] is None


def test_a_node_process_freezes_what_start_up_left_so_collections_skip_it() -> None:
    import gc

    from gldt_ros.runtime.node_base import freeze_start_up_objects

    try:
        freeze_start_up_objects()
        frozen = gc.get_freeze_count()
        assert frozen > 1000  # the modules and objects of this test process
        made = [[index] for index in range(100)]  # what a frame makes later stays collectable
        assert gc.get_freeze_count() == frozen and all(gc.is_tracked(item) for item in made)
    finally:
        gc.unfreeze()
