"""``scripts/train_on_gpu.sh`` and ``scripts/train_long.sh`` on the CPU, with configs shrunk to seconds.

The GPU script runs only where a GPU is lent, a few minutes at a time, so a fault in it costs the
whole lease: it once pointed at a configs folder that had moved, and once decoded the clips on
one core because ``nproc`` honours the ``OMP_NUM_THREADS=1`` it exports. Here both scripts run
every phase on synthetic scenes and resume a committed checkpoint.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

torch = pytest.importorskip("torch", reason="training is the optional `train` extra")

from gldt_core.training.train import load_config, train  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "scripts" / "train_on_gpu.sh"
LONG_CONFIG = REPO / "src" / "gldt_core" / "configs" / "train" / "local_wide_long.yaml"

SHRUNK = """extends: {base}
data:
  use_real: false
  real_validation: false
  synthetic_val_scenes: 1
  synthetic_scenes: 1
  synthetic_frames: 16
  synthetic_frame_step: 8
  val_max_images: 2
  input_size: [64, 64]
  val_size: [64, 64]
  roi: 75
  val_roi: 75
  cache_dir: {cache}
train: {{epochs: 3, steps_per_epoch: 2, batch_size: 2, warmup_steps: 1}}
"""


def checkout_with_one_committed_epoch(tmp_path: Path) -> tuple[Path, Path]:
    """``(configs, checkout)``: the shrunk long config, and a checkout root (``src/``) whose
    ``checkpoints/local_wide_long/last.pt`` holds the first of its three epochs, as committed."""
    configs = tmp_path / "configs"
    configs.mkdir()
    (configs / "local_wide_long.yaml").write_text(SHRUNK.format(base=LONG_CONFIG, cache=tmp_path / "cache"))
    root = tmp_path / "checkout"  # the scripts work from a checkout's root: src/, checkpoints/, runs/
    root.mkdir()
    (root / "src").symlink_to(REPO / "src")
    config = load_config(configs / "local_wide_long.yaml")
    config["train"]["device"] = "cpu"
    train("local", config, out_dir=tmp_path / "earlier", progress=False, stop_after_s=0.0)  # one epoch of three
    committed = root / "checkpoints" / "local_wide_long" / "last.pt"
    committed.parent.mkdir(parents=True)
    (tmp_path / "earlier" / "last.pt").rename(committed)
    return configs, root


def test_the_gpu_script_trains_packs_and_resumes_a_committed_checkpoint(tmp_path: Path) -> None:
    configs, root = checkout_with_one_committed_epoch(tmp_path)

    env = {
        **os.environ,
        "DEVICE": "cpu",
        "CONFIGS": str(configs),
        "PYTHON": sys.executable,
        "RUNS": "local:local_wide_long",
        "OMP_NUM_THREADS": "1",
    }
    done = subprocess.run(
        ["bash", str(SCRIPT), str(tmp_path / "result"), "200"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "local_wide_long: resumes checkpoints/local_wide_long/last.pt" in done.stdout
    cores = len(os.sched_getaffinity(0))
    assert f"with {cores} workers" in done.stdout, "the data phase must use every core, whatever OMP_NUM_THREADS says"

    checkpoint = torch.load(root / "runs" / "local_wide_long" / "last.pt", map_location="cpu", weights_only=False)
    assert checkpoint["epoch"] == 3 and checkpoint["resume"]["step"] == 6, "the run went on from epoch 1 to its end"
    with tarfile.open(tmp_path / "result" / "local_wide_long.tar.gz") as packed:
        names = packed.getnames()
    assert "runs/local_wide_long/last.pt" in names and "runs/local_wide_long/stdout.txt" in names


@pytest.mark.parametrize(
    ("runs", "message"),
    [
        ("local_wide_long", "bad run 'local_wide_long'"),
        ("detector:local_wide_long", "bad run 'detector:local_wide_long'"),
        ("local:no_such_config", "training config not found"),
        ("  ", "RUNS names no run"),
    ],
)
def test_the_gpu_script_refuses_a_bad_run_list_in_one_line_before_it_starts(
    tmp_path: Path, runs: str, message: str
) -> None:
    env = {**os.environ, "DEVICE": "cpu", "PYTHON": sys.executable, "RUNS": runs}
    done = subprocess.run(
        ["bash", str(SCRIPT), str(tmp_path / "result"), "200"], cwd=REPO, env=env, capture_output=True, text=True
    )
    assert done.returncode == 2
    assert message in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "smoke" not in done.stdout and not (tmp_path / "result").exists()


def test_the_long_run_script_resumes_a_committed_checkpoint_and_puts_it_back(tmp_path: Path) -> None:
    """scripts/train_long.sh: the CPU's share of a long run between GPU leases."""
    configs, root = checkout_with_one_committed_epoch(tmp_path)
    committed = root / "checkpoints" / "local_wide_long" / "last.pt"

    env = {**os.environ, "CONFIGS": str(configs), "PYTHON": sys.executable}
    done = subprocess.run(
        ["bash", str(REPO / "scripts" / "train_long.sh"), "120", "local_wide_long"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "--resume checkpoints/local_wide_long/last.pt" in done.stdout
    checkpoint = torch.load(committed, map_location="cpu", weights_only=False)
    assert checkpoint["epoch"] == 3, "the committed checkpoint is the run's state after this session"
    with (committed.parent / "log.csv").open() as fh:
        epochs = [int(row["epoch"]) for row in csv.DictReader(fh)]
    assert epochs == [1, 2, 3], "the committed log is the whole run's, epoch by epoch"
