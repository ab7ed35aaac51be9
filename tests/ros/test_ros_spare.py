"""gldt_ros.runtime.spare: the warm spare refuses bad requests in one line and exits on end of input."""

from __future__ import annotations

import io

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.runtime import spare  # noqa: E402


@pytest.mark.parametrize(
    "request_line, complaint",
    [
        ("not json\n", "bad request"),
        ('["no_such_node"]\n', "expected one of"),
        ('["mode_scheduler", 3]\n', "string arguments"),
        ('[["mode_scheduler"]]\n', "expected one of"),
        ("{}\n", "bad request"),
        ('{"mode_scheduler": 1}\n', "expected a JSON list"),
        ("[]\n", "bad request"),
    ],
)
def test_a_bad_request_is_refused_in_one_line(
    request_line: str, complaint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert spare.become_node(request_line) == 2
    out = capsys.readouterr().out
    assert complaint in out and len(out.strip().splitlines()) == 1


def test_end_of_input_without_a_request_exits_cleanly() -> None:
    """The pipeline stopping closes the spare's stdin: it must exit 0, not wait or crash."""
    assert spare.main(stdin=io.StringIO("")) == 0


class _WaitingSpare:
    """Stands in for a spare process that is up and waiting."""

    stdin = None
    returncode = None

    def poll(self) -> None:
        return None


@pytest.mark.parametrize("delay, expect_spare", [(None, False), ("0", True)])
def test_the_spare_waits_out_the_start_up_unless_told_not_to(
    monkeypatch: pytest.MonkeyPatch, delay: str | None, expect_spare: bool
) -> None:
    """Its imports would compete with the nodes' first frames, so by default the first spare comes
    ``--spare-delay`` seconds after start-up, as after a restart; gldt_ros.bench.restart and the kill tests
    ask for it at once (0)."""
    from gldt_ros.launcher import pipeline

    launched: list[list[str]] = []

    def popen(command: list[str], **_: object) -> _WaitingSpare:
        launched.append(command)
        return _WaitingSpare()

    monkeypatch.setattr(pipeline.NodeProcesses, "_start", lambda self, name: None)  # no node processes
    monkeypatch.setattr(pipeline.subprocess, "Popen", popen)
    args = pipeline.parse_args(["--spare-delay", delay] if delay is not None else [])
    assert (
        args.spare_delay == (float(delay) if delay is not None else pipeline.SPARE_DELAY_S)
        and pipeline.SPARE_DELAY_S > 0
    )
    children = pipeline.NodeProcesses(args)
    children.supervising = True
    children.keep_spare()
    assert (children.spare is not None) == expect_spare
    assert launched == ([[pipeline.sys.executable, "-m", "gldt_ros.runtime.spare"]] if expect_spare else [])


@pytest.mark.parametrize("value", ["-1", "inf", "nan"])
def test_a_bad_spare_delay_is_refused(value: str, capsys: pytest.CaptureFixture[str]) -> None:
    from gldt_ros.launcher.pipeline import parse_args

    with pytest.raises(SystemExit):
        parse_args(["--spare-delay", value])
    assert "--spare-delay must be a number of seconds >= 0" in capsys.readouterr().err
