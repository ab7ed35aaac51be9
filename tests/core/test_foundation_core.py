"""The core stays free of ROS and torch, and the ``gldt`` command lists its subcommands."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from support import CORE_SRC

# Packages allowed to import torch: training and export only, never imported by the runtime.
TORCH_PACKAGES = ("gldt_core.training", "gldt_core.export.onnx_export")


def _python(code: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)


def test_import_gldt_core_pulls_in_neither_rclpy_nor_torch() -> None:
    result = _python(
        "import sys, gldt_core\n"
        "bad = [m for m in ('rclpy', 'torch', 'gldt_msgs') if m in sys.modules]\n"
        "print(','.join(bad))"
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "", f"import gldt_core imported {result.stdout.strip()}"


def test_every_runtime_module_is_free_of_rclpy_and_torch() -> None:
    """Import every gldt_core module except the training package and check sys.modules."""
    code = f"""
import importlib, pkgutil, sys
import gldt_core
skipped = {TORCH_PACKAGES!r}
names = []
for info in pkgutil.walk_packages(gldt_core.__path__, 'gldt_core.', onerror=lambda name: None):
    if info.name.startswith(skipped) or info.name.endswith('.__main__'):
        continue
    importlib.import_module(info.name)
    names.append(info.name)
bad = [m for m in ('rclpy', 'torch') if m in sys.modules]
print(len(names), ','.join(bad))
"""
    result = _python(code)
    assert result.returncode == 0, result.stderr[-2000:]
    count, _, bad = result.stdout.strip().partition(" ")
    assert int(count) >= 5, f"expected the core's modules to be walked, got {count}"
    assert bad == "", f"runtime modules imported {bad}"


def test_gldt_help_lists_every_subcommand_module() -> None:
    expected = sorted(path.stem for path in (CORE_SRC / "cli").glob("*.py") if not path.stem.startswith("_"))
    result = subprocess.run([sys.executable, "-m", "gldt_core", "--help"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    for command in expected:
        assert command in result.stdout, f"`gldt --help` does not list {command!r}:\n{result.stdout}"
    for required in ("bench", "track", "eval", "synth", "bag"):
        assert required in expected, f"subcommand module cli/{required}.py is missing"


def test_gldt_console_script_is_installed() -> None:
    script = Path(sys.executable).parent / "gldt"
    assert script.is_file(), f"console script missing at {script}"
    result = subprocess.run([str(script), "--version"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and result.stdout.startswith("gldt "), result.stdout + result.stderr


def test_unknown_subcommand_fails_with_one_line() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "gldt_core", "no-such-command"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert "invalid choice" in result.stderr
    assert "Traceback" not in result.stderr
