"""One real training step of each detector: the loop learns (weights move), logs and checkpoints.

The full runs take tens of minutes (``gldt train``); this catches what breaks them early, such
as a forward pass left under ``no_grad`` or a checkpoint that does not load back.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="training is the optional `train` extra")

from gldt_core.training.train import load_checkpoint, spec_for_task, train  # noqa: E402


@pytest.fixture(scope="module")
def data_cache(tmp_path_factory) -> Path:
    """Rendered synthetic scenes, shared by the tests (rendering them is most of the run time)."""
    return tmp_path_factory.mktemp("train_cache")


def tiny_config(task: str, cache_dir: Path) -> dict:
    """The shipped config's schema, shrunk to seconds: one synthetic scene, two steps."""
    from gldt_core.training.train import DEFAULTS, merge_config

    override = {
        "threads": 1,
        "model": {"channels": [4, 8, 8, 16, 16], "depth": 1, "num_classes": 3, "reg_max": 8, "head_levels": [2, 3]},
        "data": {
            "cache_dir": str(cache_dir),
            "use_real": False,
            "real_validation": False,  # runs without the Halmstad clips beside the checkout
            "synthetic_val_scenes": 1,
            "synthetic_scenes": 1,
            "synthetic_frames": 16,
            "synthetic_frame_step": 8,
            "synthetic_scale": 1.0 / 3.0 if task == "global" else 1.0,
            "val_max_images": 2,
            "input_size": [96, 64] if task == "global" else [64, 64],
            "val_size": [128, 96] if task == "global" else [64, 64],
            "roi": 75,
            "val_roi": 75,
        },
        "train": {"epochs": 1, "batch_size": 2, "steps_per_epoch": 2, "warmup_steps": 1, "lr": 0.01, "ema_decay": 0.0},
    }
    if task == "global":
        override["model"].update({"dual_frame": True, "stff_levels": [2], "stff_windows": [4]})
    else:
        override["model"].update({"dual_frame": False, "stff_levels": [], "stff_windows": []})
    return merge_config(DEFAULTS, override)


@pytest.mark.parametrize("task", ["global", "local"])
def test_one_epoch_of_training_moves_the_weights_and_writes_a_loadable_checkpoint(
    task: str, tmp_path: Path, data_cache: Path
) -> None:
    from gldt_core.training.models import Detector

    config = tiny_config(task, data_cache)
    torch.manual_seed(config["seed"])
    initial = Detector(spec_for_task(task, config)).state_dict()
    best = train(task, config, out_dir=tmp_path / "run", progress=False)

    model, checkpoint = load_checkpoint(best)
    assert checkpoint["task"] == task and checkpoint["epoch"] == 1
    moved = [
        name
        for name, value in model.state_dict().items()
        if value.dtype.is_floating_point and not torch.equal(value, initial[name])
    ]
    assert moved, "no weight changed: the training step did not reach the optimiser"
    with (tmp_path / "run" / "log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 1 and math.isfinite(float(rows[0]["loss"])) and float(rows[0]["loss"]) > 0
    assert (tmp_path / "run" / "curves.png").is_file()
    h, w = config["data"]["val_size"][1], config["data"]["val_size"][0]
    image = torch.zeros(1, 3, h, w)
    with torch.no_grad():
        out = model(image, image) if task == "global" else model(image)
    assert np.isfinite(out.numpy()).all()


def test_parallel_scene_rendering_caches_the_same_pairs_as_serial(tmp_path: Path) -> None:
    from gldt_core.training.data import load_synthetic

    serial = load_synthetic("train", 2, 10, 4, 0.25, tmp_path / "serial", workers=0)
    parallel = load_synthetic("train", 2, 10, 4, 0.25, tmp_path / "parallel", workers=2)
    assert [(p.source, p.frame) for p in parallel] == [(p.source, p.frame) for p in serial]
    assert len({p.source for p in serial}) == 2
    for a, b in zip(serial, parallel):
        assert a.current == b.current and a.previous == b.previous
        np.testing.assert_array_equal(a.boxes, b.boxes)


def test_wall_clock_budget_ends_the_schedule_after_the_first_step_with_a_checkpoint(
    tmp_path: Path, data_cache: Path
) -> None:
    config = tiny_config("local", data_cache)
    config["train"].update({"epochs": 3, "steps_per_epoch": 4, "max_wall_s": 1e-6, "loader_workers": 1})
    best = train("local", config, out_dir=tmp_path / "run", progress=False)
    _, checkpoint = load_checkpoint(best)
    with (tmp_path / "run" / "log.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert checkpoint["epoch"] == 1 and len(rows) == 1, "a spent budget must stop the schedule after epoch 1"
    assert float(rows[0]["lr"]) == pytest.approx(config["train"]["lr"] * 0.05), (
        "the schedule must have annealed to its floor"
    )


def test_asking_for_cuda_without_one_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from gldt_core.training.train import resolve_device

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # the same on a machine with a GPU
    with pytest.raises(ValueError, match="sees no CUDA device"):
        resolve_device("cuda")
    assert resolve_device("auto").type == "cpu"


def test_without_a_budget_the_learning_rate_follows_warmup_and_cosine_of_the_steps_taken(
    tmp_path: Path, data_cache: Path
) -> None:
    config = tiny_config("local", data_cache)
    config["train"].update({"epochs": 2, "steps_per_epoch": 2, "warmup_steps": 3})
    train("local", config, out_dir=tmp_path / "run", progress=False)
    with (tmp_path / "run" / "log.csv").open() as fh:
        rates = [float(row["lr"]) for row in csv.DictReader(fh)]
    total = 4

    def expected(steps: int) -> float:
        return (
            config["train"]["lr"]
            * min(1.0, (steps + 1) / 3)
            * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * steps / total)))
        )

    assert rates == pytest.approx([expected(2), expected(4)])


def test_a_detector_run_stopped_and_resumed_ends_with_the_same_weights(tmp_path: Path, data_cache: Path) -> None:
    """Three epochs straight and three epochs as 1 + 2 sessions (--stop-after-s 0, then --resume
    last.pt) give identical weights: the data order, augmentation, schedule, optimiser and EMA
    all carry over; the time spent adds up by device."""
    config = tiny_config("local", data_cache)
    config["train"].update(epochs=3, ema_decay=0.9)
    straight, _ = load_checkpoint(
        train("local", config, out_dir=tmp_path / "straight", progress=False).with_name("last.pt")
    )

    train("local", config, out_dir=tmp_path / "split", progress=False, stop_after_s=0.0)
    first = torch.load(tmp_path / "split" / "last.pt", map_location="cpu", weights_only=False)
    assert first["epoch"] == 1 and first["resume"]["step"] == 2
    train("local", config, out_dir=tmp_path / "split", progress=False, resume=tmp_path / "split" / "last.pt")
    resumed, checkpoint = load_checkpoint(tmp_path / "split" / "last.pt")

    assert checkpoint["epoch"] == 3 and checkpoint["resume"]["step"] == 6
    for (name, a), b in zip(straight.state_dict().items(), resumed.state_dict().values()):
        assert torch.equal(a, b), f"{name} differs after a resume"
    assert checkpoint["train_wall_s_by_device"]["cpu"] > first["train_wall_s_by_device"]["cpu"]
    assert len(checkpoint["resume"]["rows"]) == 3


def test_a_resume_against_another_network_or_schedule_is_refused_in_one_line(tmp_path: Path, data_cache: Path) -> None:
    from gldt_core.training.resume import ResumeError

    config = tiny_config("local", data_cache)
    train("local", config, out_dir=tmp_path / "run", progress=False)
    last, best = tmp_path / "run" / "last.pt", tmp_path / "run" / "best.pt"
    config["train"]["epochs"] = 3  # the run above stops after its single epoch, so it is resumable here
    longer = tiny_config("local", data_cache)
    longer["train"]["epochs"] = 4
    faster = tiny_config("local", data_cache)
    faster["train"]["lr"] = 0.02
    squeezed = tiny_config("local", data_cache)
    squeezed["train"]["max_wall_s"] = 60
    wider = tiny_config("local", data_cache)
    wider["model"]["channels"] = [8, 8, 8, 16, 16]
    (tmp_path / "broken.pt").write_bytes(b"not a checkpoint")
    cases = [
        ("global", tiny_config("global", data_cache), last, "is a local checkpoint, this run trains global"),
        ("local", tiny_config("local", data_cache), last, "finished its schedule \\(epoch 1 of 1\\)"),
        ("local", longer, last, "another schedule \\(epochs 1 -> 4\\)"),
        ("local", faster, last, "another schedule \\(lr 0.01 -> 0.02\\)"),
        ("local", squeezed, last, "cannot resume a schedule squeezed into train.max_wall_s"),
        ("local", wider, last, "has the network"),
        ("local", config, best, "holds no training state"),
        ("local", config, tmp_path / "second_stage.pt", "is not a detector checkpoint"),
        ("local", config, tmp_path / "missing.pt", "checkpoint not found"),
        ("local", config, tmp_path / "broken.pt", "is not a readable checkpoint"),
    ]
    torch.save({"kind": "second_stage"}, tmp_path / "second_stage.pt")
    for task, cfg, path, message in cases:
        with pytest.raises(ResumeError, match=message) as caught:
            train(task, cfg, out_dir=tmp_path / "again", progress=False, resume=path)
        assert "\n" not in str(caught.value)
    assert not (tmp_path / "again").exists(), "a refused resume wrote into the run folder"


def test_a_run_started_from_another_runs_weights_keeps_their_training_time(tmp_path: Path, data_cache: Path) -> None:
    config = tiny_config("local", data_cache)
    first = train("local", config, out_dir=tmp_path / "first", progress=False)
    spent_first = torch.load(first, map_location="cpu", weights_only=False)["train_wall_s_by_device"]["cpu"]
    train("local", config, out_dir=tmp_path / "second", progress=False, init_from=first)
    train("local", config, out_dir=tmp_path / "scratch", progress=False)
    second, checkpoint = load_checkpoint(tmp_path / "second" / "last.pt")
    scratch, _ = load_checkpoint(tmp_path / "scratch" / "last.pt")
    assert any(not torch.equal(a, b) for a, b in zip(second.state_dict().values(), scratch.state_dict().values())), (
        "a run started from another run's weights ended where a run from scratch did"
    )
    assert checkpoint["train_wall_s_by_device"]["cpu"] > spent_first
    assert checkpoint["data"]["initial_weights"] == str(first)
    assert checkpoint["resume"]["step"] == 2, "--init-from starts the config's schedule from its first step"


def test_a_session_resumed_into_another_folder_does_not_take_a_stale_best_for_its_own(
    tmp_path: Path, data_cache: Path
) -> None:
    """best.pt belongs to one run: resumed into a folder whose best.pt came from another run, the
    run keeps its own best from its next epoch on instead of comparing against a stranger's."""
    config = tiny_config("local", data_cache)
    config["train"]["epochs"] = 3
    train("local", config, out_dir=tmp_path / "a", progress=False, stop_after_s=0.0)
    other = tiny_config("local", data_cache)
    other["seed"] = 1
    train("local", other, out_dir=tmp_path / "b", progress=False)  # leaves another run's best.pt in b
    stranger = torch.load(tmp_path / "b" / "best.pt", map_location="cpu", weights_only=False)
    train("local", config, out_dir=tmp_path / "b", progress=False, resume=tmp_path / "a" / "last.pt")
    ours = torch.load(tmp_path / "b" / "best.pt", map_location="cpu", weights_only=False)
    first = torch.load(tmp_path / "a" / "last.pt", map_location="cpu", weights_only=False)
    assert ours["run_id"] == first["resume"]["run_id"] != stranger["run_id"]
    assert ours["epoch"] == 2, "the resumed run's first epoch is its best in a folder it had no best in"


class _ThreadCounts(torch.utils.data.Dataset):
    def __len__(self) -> int:
        return 2

    def __getitem__(self, index: int) -> tuple[int, int]:
        import cv2

        return cv2.getNumThreads(), torch.get_num_threads()


def test_a_loader_worker_decodes_on_one_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """OpenCV sizes its pool by the machine's cores, not OMP_NUM_THREADS: on a 16-core GPU machine
    every loader worker would start 16 threads."""
    import cv2

    from gldt_core.training.train import one_thread_worker

    previous = cv2.getNumThreads()
    cv2.setNumThreads(4)  # what a many-core machine gives a fresh process
    try:
        loader = torch.utils.data.DataLoader(
            _ThreadCounts(), batch_size=None, num_workers=1, worker_init_fn=one_thread_worker
        )
        assert [tuple(map(int, item)) for item in loader] == [(1, 1), (1, 1)]
    finally:
        cv2.setNumThreads(previous)
