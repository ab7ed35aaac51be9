"""gldt_ros.runtime.spare and node_group: a bad request or group is refused in one line; the spare
exits on end of input."""

from __future__ import annotations

import io

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.runtime import node_group, spare  # noqa: E402


@pytest.mark.parametrize(
    "request_line, complaint",
    [
        ("not json\n", "not JSON"),
        ('[["no_such_node"]]\n', "expected one of"),
        ('[["mode_scheduler", 3]]\n', "string arguments"),
        ('["mode_scheduler"]\n', "expected a [node, arguments...] list"),
        ('[[["mode_scheduler"]]]\n', "expected one of"),
        ('[["mode_scheduler"], ["mode_scheduler"]]\n', "named twice"),
        ("{}\n", "non-empty JSON list"),
        ('{"mode_scheduler": 1}\n', "non-empty JSON list"),
        ("[]\n", "non-empty JSON list"),
    ],
)
def test_a_bad_request_is_refused_in_one_line(
    request_line: str, complaint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert spare.become_node(request_line) == 2
    out = capsys.readouterr().out
    assert complaint in out and len(out.strip().splitlines()) == 1
    assert node_group.main([request_line.strip()]) == 2, "a group process takes the same list"
    out = capsys.readouterr().out
    assert complaint in out and len(out.strip().splitlines()) == 1


def test_a_group_request_names_each_node_with_its_own_arguments() -> None:
    from gldt_ros.launcher.pipeline import group_description, parse_args

    args = parse_args(["--lockstep", "--namespace", "cam", "--processes", "grouped"])
    group = node_group.parse_group(group_description(["frame_pair_buffer", "mode_scheduler"], args))
    assert [name for name, _ in group] == ["frame_pair_buffer", "mode_scheduler"]
    buffer_args, scheduler_args = (arguments for _, arguments in group)
    assert "skip_global_when_busy:=false" in buffer_args and "lockstep:=true" in scheduler_args
    assert "lockstep:=true" not in buffer_args, "a node's overrides stay its own"
    assert all("__ns:=/cam" in arguments for _, arguments in group)


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
