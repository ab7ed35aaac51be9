"""gldt_ros.dds_profile: the shipped Fast DDS profile loads, and a restarted node's copy of it
gives the node the participant id it names (so it does not inherit a dead process's ports)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from conftest import isolated_ros_env  # noqa: E402

from gldt_ros import dds_profile  # noqa: E402
from gldt_ros.dds_profile import DDS_PROFILE_VARIABLE, RestartProfiles, with_participant_id  # noqa: E402

#: Starts a participant and prints the user-traffic port Fast DDS gave it: the shared-memory
#: lock file ``fastrtps_port<N>_el`` it holds, N = 7400 + 250 * domain + 11 + 2 * participant id.
PORT_PROBE = """
import os, re, rclpy
rclpy.init(); node = rclpy.create_node('profile_probe')
held = []
for fd in os.listdir('/proc/self/fd'):
    try:
        held.append(os.readlink(f'/proc/self/fd/{fd}'))
    except OSError:
        pass
ports = sorted(int(m.group(1)) for path in held if (m := re.search(r'fastrtps_port(\\d+)_el$', path)))
node.destroy_node(); rclpy.shutdown()
print('ports', *ports)
"""


def probe(profile: Path) -> tuple[str, list[int], int]:
    """Start one participant with ``profile`` in a domain of its own; return its output, the
    shared-memory ports it holds and the domain."""
    env = isolated_ros_env()
    env[DDS_PROFILE_VARIABLE] = str(profile)
    result = subprocess.run(
        [sys.executable, "-c", PORT_PROBE], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout
    last = result.stdout.rstrip().splitlines()[-1]
    assert last.startswith("ports"), result.stdout
    return result.stdout, [int(port) for port in last.split()[1:]], int(env["ROS_DOMAIN_ID"])


def test_participant_id_goes_into_the_participant_profile() -> None:
    text = dds_profile.shipped_profile().read_text()
    copy = with_participant_id(text, 61)
    assert copy.count("<participantID>61</participantID>") == 1
    assert copy.index("<participantID>") > copy.index('<participant profile_name="gldt_participant"')
    with pytest.raises(ValueError, match="range"):
        with_participant_id(text, 120)
    with pytest.raises(ValueError, match="<rtps>"):
        with_participant_id("<profiles/>", 61)


def test_restart_profiles_hand_out_fresh_ids_under_the_shipped_profile_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, str(dds_profile.shipped_profile()))
    profiles = RestartProfiles()
    first, second = profiles.environment_for_restart(), profiles.environment_for_restart()
    paths = [Path(first[DDS_PROFILE_VARIABLE]), Path(second[DDS_PROFILE_VARIABLE])]
    assert "<participantID>60</participantID>" in paths[0].read_text()
    assert "<participantID>61</participantID>" in paths[1].read_text()
    profiles.close()
    assert not paths[0].parent.exists(), "close() must remove the copies"
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, "/etc/my_profile.xml")
    assert RestartProfiles().environment_for_restart() == {}, "a profile the user chose is left alone"


def test_a_restart_without_a_profile_copy_falls_back_to_the_shipped_profile(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """No room for the copy (say /tmp is full) must not stop the restart itself."""
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, str(dds_profile.shipped_profile()))

    def full(*_args, **_kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(dds_profile.tempfile, "mkdtemp", full)
    assert RestartProfiles().environment_for_restart() == {}
    assert "No space left on device" in capsys.readouterr().out


def test_a_restart_copy_loads_cleanly_and_fast_dds_takes_its_participant_id(monkeypatch: pytest.MonkeyPatch) -> None:
    """The id must reach Fast DDS: with the shipped profile a lone participant takes id 0 (the
    lowest free); with a restart copy it takes the copy's id, which shows in its port number."""
    monkeypatch.setenv(DDS_PROFILE_VARIABLE, str(dds_profile.shipped_profile()))
    profiles = RestartProfiles()
    try:
        copy = Path(profiles.environment_for_restart()[DDS_PROFILE_VARIABLE])
        output, ports, domain = probe(copy)
        assert "XMLPARSER" not in output, output
        assert 7400 + 250 * domain + 11 + 2 * 60 in ports, output
        output, ports, domain = probe(dds_profile.shipped_profile())
        assert 7400 + 250 * domain + 11 + 2 * 60 not in ports, output
    finally:
        profiles.close()
