"""The set-up command fails loudly, in one line naming the step and the cause, without side effects."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from support import REPO_ROOT

SETUP = REPO_ROOT / "scripts" / "setup.sh"


def _run_setup(env_changes: dict[str, str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env.update(env_changes)
    return subprocess.run(["bash", str(SETUP)], capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path)


def _stamp_snapshot() -> dict[str, str]:
    stamps = REPO_ROOT / ".setup-stamps"
    return {p.name: p.read_text() for p in stamps.glob("*")} if stamps.is_dir() else {}


def test_wrong_python_is_named(tmp_path: Path) -> None:
    fake = tmp_path / "python-2.7"
    fake.write_text("#!/bin/sh\nexit 1\n")
    fake.chmod(0o755)
    before = _stamp_snapshot()
    result = _run_setup({"PYTHON": str(fake)}, tmp_path)
    assert result.returncode != 0
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("setup: python:"), result.stderr
    assert "3.11" in lines[0]
    assert _stamp_snapshot() == before, "a failed set-up must not touch the stamps of finished steps"


def test_missing_cmake_is_named(tmp_path: Path) -> None:
    # A PATH holding only what the script needs before its tool check, and no cmake.
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("bash", "dirname", "mkdir", "cat", "sha256sum", "cut", "python3", "g++", "make"):
        found = shutil.which(tool)
        if found:
            (bin_dir / tool).symlink_to(found)
    result = _run_setup({"PATH": str(bin_dir), "PYTHON": ""}, tmp_path)
    assert result.returncode != 0
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == [lines[0]] and lines[0].startswith("setup: tools: cmake not found"), result.stderr


def test_rerun_on_a_set_up_machine_skips_every_step(tmp_path: Path) -> None:
    result = _run_setup({}, tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines() == ["setup: ready (venv: .venv, ROS workspace: install/)"], (
        "a rerun should only report ready, not redo steps:\n" + result.stdout
    )
