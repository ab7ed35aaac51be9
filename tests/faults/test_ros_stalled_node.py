"""Issue 31: a node that stops answering (SIGSTOP here; a deadlock looks the same from outside) is
noticed by its missing heartbeat within 2 s and restarted like a dead one, and the replay goes on.

The watch's logic is tested without a graph in ``tests/ros/test_ros_heartbeat.py``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from support import REAL_BAG, PipelineRun, isolated_ros_env

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_ros.interface.graph import NODES  # noqa: E402


def recorded_stamps(path: Path) -> list[int]:
    """Header stamps of the ``/gldt/tracks`` messages readable in ``path`` (written as we read)."""
    from gldt_core.io.recording import iter_recorded
    from gldt_ros.interface.convert import stamp_nanoseconds

    stamps: list[int] = []
    if not path.is_file():
        return stamps
    try:
        for _, message, _ in iter_recorded(path, "gldt/tracks"):
            stamps.append(stamp_nanoseconds(message.header.stamp))
    except ValueError:
        pass
    return stamps


@pytest.mark.parametrize("victim", NODES)
def test_a_stopped_node_is_restarted_and_the_replay_goes_on(tmp_path: Path, victim: str) -> None:
    """SIGSTOP one node mid-replay (lockstep, so the replay waits on it): ``pipeline`` says it sent
    no heartbeat, kills and restarts it, relinks the graph, and the later frames are answered.
    No other node is judged silent at any time of the replay."""
    record = tmp_path / "graph.mcap"
    env = isolated_ros_env()
    del env["ROS_DOMAIN_ID"]  # a free domain of pipeline's own: no other test's graph can meet this one
    # --spare-delay 0: the restart uses the warm spare, as a restart long after start-up would.
    per_node = ["--spare-delay", "0", "--processes", "per-node"]  # this test stops one node, alone in its process
    run = PipelineRun(["--bag", str(REAL_BAG), "--lockstep", "--record", str(record), *per_node], env)
    stopped_pid: int | None = None
    try:
        deadline = time.monotonic() + 120.0
        while not run.with_text("nodes up"):
            assert run.process.poll() is None, "pipeline ended before its nodes were up:\n" + run.text
            assert time.monotonic() < deadline, "the nodes were not up after 120 s:\n" + run.text
            time.sleep(0.05)
        time.sleep(1.0)  # into the replay (150 frames take 3 s and more in lockstep)
        assert run.process.poll() is None and not run.with_text("pipeline: sent "), "the replay ended before the stop"
        stopped_pid = int(run.with_text(f"started {victim} (pid ")[0][1].split("(pid ")[1].split(")")[0])
        os.kill(stopped_pid, signal.SIGSTOP)
        stopped_at = time.monotonic()
        try:
            code = run.process.wait(timeout=300.0)
        except subprocess.TimeoutExpired:
            pytest.fail("pipeline did not end 300 s after the stop:\n" + run.text)
        run._reader.join(timeout=5.0)
    finally:
        if run.process.poll() is None:
            run.process.kill()
            run.process.wait()
        if stopped_pid is not None:
            try:
                os.kill(stopped_pid, signal.SIGKILL)  # pipeline did, unless the test failed first
            except ProcessLookupError:
                pass
    text = run.text
    assert code in (0, 3), text  # 3: the frame in flight when the node stopped was given up
    judged = run.with_text("sent no heartbeat")
    assert [line for _, line in judged] == [
        line for _, line in judged if f"node {victim} " in line and "killing and restarting (1/5)" in line
    ], text
    assert len(judged) == 1, f"expected one heartbeat restart, of {victim} only:\n{text}"
    detected_s = judged[0][0] - stopped_at
    silent_s = float(judged[0][1].split("sent no heartbeat for ")[1].split(" s")[0])
    print(f"{victim}: restarted {detected_s:.2f} s after SIGSTOP ({silent_s:.1f} s since its last status)")
    assert detected_s < 5.0, f"the stopped node was restarted only {detected_s:.1f} s later:\n{text}"
    assert not run.with_text("exited with code"), "no node should have died or been restarted otherwise:\n" + text
    assert len(run.with_text(f"{victim} ready")) == 2, f"{victim} should have come up twice:\n{text}"
    relinked = run.with_text("graph linked again")
    assert len(relinked) == 1 and victim in relinked[0][1], text
    first_after = int(relinked[0][1].rsplit("next frame stamped ", 1)[1])
    stamps = recorded_stamps(record)
    assert stamps == sorted(stamps), "tracks out of frame order"
    assert first_after in stamps, f"the first frame after the restart went unanswered:\n{text}"
    assert len([stamp for stamp in stamps if stamp >= first_after]) >= 20, "too few frames tracked after the restart"
