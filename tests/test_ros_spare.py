"""gldt_ros.spare: the warm spare refuses bad requests in one line and exits on end of input."""

from __future__ import annotations

import io

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros import spare  # noqa: E402


@pytest.mark.parametrize(
    "request_line, complaint",
    [
        ("not json\n", "bad request"),
        ('["no_such_node"]\n', "expected one of"),
        ('["mode_scheduler", 3]\n', "string arguments"),
        ("{}\n", "bad request"),
        ('{"mode_scheduler": 1}\n', "expected a JSON list"),
        ("[]\n", "bad request"),
    ],
)
def test_a_bad_request_is_refused_in_one_line(request_line: str, complaint: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert spare.become_node(request_line) == 2
    out = capsys.readouterr().out
    assert complaint in out and len(out.strip().splitlines()) == 1


def test_end_of_input_without_a_request_exits_cleanly() -> None:
    """The pipeline stopping closes the spare's stdin: it must exit 0, not wait or crash."""
    assert spare.main(stdin=io.StringIO("")) == 0
