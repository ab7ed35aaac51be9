"""gldt_ros.spare: the warm spare refuses bad requests in one line and exits on end of input."""

from __future__ import annotations

import io
import os
import sys

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros import spare  # noqa: E402


@pytest.mark.parametrize(
    "request_line, complaint",
    [
        ("not json\n", "bad request"),
        ('["mode_scheduler"]\n', "bad request"),
        ('{"node": "mode_scheduler", "arguments": []}\n', "KeyError"),
        ('{"node": "no_such_node", "arguments": [], "environment": {}}\n', "expected one of"),
        ('{"node": "mode_scheduler", "arguments": [3], "environment": {}}\n', "string arguments"),
        ('{"node": "mode_scheduler", "arguments": "--ros-args", "environment": {}}\n', "string arguments"),
        ('{"node": "mode_scheduler", "arguments": [], "environment": {"A": 1}}\n', "string-to-string environment"),
    ],
)
def test_a_bad_request_is_refused_in_one_line(request_line: str, complaint: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert spare.become_node(request_line) == 2
    out = capsys.readouterr().out
    assert complaint in out and len(out.strip().splitlines()) == 1


def test_the_pipeline_request_is_one_the_spare_accepts(monkeypatch: pytest.MonkeyPatch) -> None:
    """What ``pipeline`` writes is what the spare parses: it sets the environment first (Fast DDS
    reads the profile variable when the node joins), then runs the node's ``main``."""
    import types

    from gldt_ros.pipeline import spare_request

    seen: dict[str, object] = {}

    def fake_main() -> int:
        seen["argv"] = list(sys.argv)
        seen["profile"] = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")
        return 7

    monkeypatch.setattr(spare.importlib, "import_module", lambda name: types.SimpleNamespace(__name__=name, main=fake_main))
    monkeypatch.setattr(sys, "argv", list(sys.argv))
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", "/shipped.xml")
    line = spare_request("mode_scheduler", ["--ros-args", "-p", "a:=1"], {"FASTRTPS_DEFAULT_PROFILES_FILE": "/restart.xml"})
    assert spare.become_node(line) == 7
    assert seen == {"argv": ["gldt_ros.nodes.mode_scheduler", "--ros-args", "-p", "a:=1"], "profile": "/restart.xml"}


def test_end_of_input_without_a_request_exits_cleanly() -> None:
    """The pipeline stopping closes the spare's stdin: it must exit 0, not wait or crash."""
    assert spare.main(stdin=io.StringIO("")) == 0
