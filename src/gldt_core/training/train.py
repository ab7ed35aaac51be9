"""Training loop for both detectors: ``gldt train global|local --config CFG``.

One YAML file fixes everything that changes the result (model spec, data, schedule, seed), and the
run directory receives: ``config.yaml`` (as resolved), ``log.csv`` (one row per epoch), ``curves.png``,
``last.pt`` and ``best.pt`` (best validation drone AP50). Validation runs after every epoch on
held-out Halmstad clips (see :mod:`gldt_core.eval.halmstad_split`) that training never sees.
An exponential moving average of the weights is what gets validated and saved: with short CPU
schedules it is markedly more stable than the raw weights.
"""

from __future__ import annotations

import copy
import csv
import math
import random
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import yaml
from torch.utils.data import DataLoader, Subset

from gldt_core.detect.postprocess import decode_output
from gldt_core.eval.detection_metrics import detection_summary
from gldt_core.eval.halmstad_split import halmstad_split
from gldt_core.paths import halmstad_root
from gldt_core.training.data import (
    CopyPaste,
    GlobalPairDataset,
    LocalCropDataset,
    collate_crops,
    collate_pairs,
    load_halmstad,
    load_synthetic,
)
from gldt_core.training.loss import DetectionLoss
from gldt_core.training.models import Detector, ModelSpec
from gldt_core.training.paste import ObjectBank
from gldt_core.training.resume import ResumeError, add_seconds, read_checkpoint

TASKS = ("global", "local")

DEFAULTS: dict[str, Any] = {
    "seed": 0,
    "threads": 2,
    "out_dir": "runs/{task}",
    "model": {},
    "data": {
        "halmstad_root": str(halmstad_root()),
        "cache_dir": "/tmp/gldt-cache",
        "train_frame_step": 10,
        "val_frame_step": 15,
        "use_real": True,
        "real_validation": True,  # validate on the held-out Halmstad clips (false: synthetic_val_scenes only)
        "synthetic_scenes": 0,  # scenes of gldt_core.sim.presets "train" (0 = real data only)
        "synthetic_frames": 120,
        "synthetic_frame_step": 8,
        "synthetic_scale": 1.0,  # resize of the 1080p frames (global: 1/3, the run-time input scale)
        "synthetic_val_scenes": 0,  # scenes of the "val" split added to validation
        # Fraction of training samples drawn from the synthetic pairs (None: every pair equally
        # likely, so the share is whatever the pair counts make it, about 20 % for the global mix).
        "synthetic_share": None,
        "input_size": [256, 256],  # training crop (w, h); global validation uses val_size
        "val_size": [640, 512],
        "roi": 300,  # training window side (frame px) for the local model; scale = input_size / roi
        "val_roi": 300,  # the runtime ROI side, used for validation at val_size
        "negative_fraction": 0.3,
        "val_max_images": 120,
        "load_workers": 0,  # processes decoding clips / rendering scenes when the cache is cold
        # Copy-paste augmentation (gldt_core.training.paste): the probability that a training sample gets
        # objects cut from other training frames matted in, how many at most, and how many objects
        # of each class the bank cuts. 0 turns it off, as in the shipped models' configs.
        "copy_paste": 0.0,
        "copy_paste_max": 3,
        "copy_paste_bank": 1500,
    },
    "train": {
        "epochs": 10,
        "batch_size": 16,
        "steps_per_epoch": 100,
        "lr": 0.002,
        "weight_decay": 0.0005,
        "warmup_steps": 50,
        "ema_decay": 0.998,
        "val_score_threshold": 0.05,
        "device": "auto",  # "auto" (cuda when torch sees one, else cpu), "cpu", "cuda", "cuda:1", ...
        "loader_workers": 0,  # DataLoader worker processes (0: augment in the training process)
        # Wall-clock budget (s) for the whole schedule, 0 = none. The cosine schedule follows
        # whichever of steps or time runs out first, so a budgeted run still anneals to its end
        # (at the price of bitwise reproducibility across machines).
        "max_wall_s": 0,
    },
}


def merge_config(base: dict[str, Any], override: dict[str, Any], where: str = "") -> dict[str, Any]:
    """``override`` over ``base``, mappings merged key by key; keys ``base`` lacks are refused."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if key not in base and base is not DEFAULTS["model"] and where != "model":
            raise ValueError(f"unknown config key {where + key!r}; known: {sorted(base)}")
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            out[key] = merge_config(base[key], value, f"{where}{key}.")
        else:
            out[key] = value
    return out


#: A training config may name another (a path relative to itself) that it changes a few keys of.
EXTENDS_KEY = "extends"


def _overlay(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``override``'s keys replaced, mappings merged key by key."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        out[key] = (
            _overlay(out[key], value)
            if isinstance(value, dict) and isinstance(out.get(key), dict)
            else copy.deepcopy(value)
        )
    return out


def _read_config(path: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The raw mapping of a training YAML with its ``extends:`` chain resolved.

    Why: a variant (another data mix, an augmentation switched on) then states only what it
    changes, so it cannot silently drift from the config it is compared against.
    """
    if not path.is_file():
        via = f" (extended by {chain[-1]})" if chain else ""
        raise FileNotFoundError(f"training config not found: {path}{via}")
    if path.resolve() in chain:
        raise ValueError(f"{path}: 'extends' makes a cycle: {' -> '.join(str(p) for p in (*chain, path.resolve()))}")
    with path.open() as fh:
        raw = yaml.safe_load(fh) or {}
    if not isinstance(raw, dict):
        raise ValueError(f"{path}: top level must be a mapping")
    base = raw.pop(EXTENDS_KEY, None)
    if base is None:
        return raw
    if not isinstance(base, str):
        raise ValueError(f"{path}: '{EXTENDS_KEY}' must be a path to another training config, got {base!r}")
    return _overlay(_read_config(path.parent / base, (*chain, path.resolve())), raw)


def load_config(path: Path | str) -> dict[str, Any]:
    """Read a training YAML (following ``extends:``) and fill defaults; unknown keys are an error
    (typos must not be silent)."""
    path = Path(path)
    raw = _read_config(path)
    config = merge_config(DEFAULTS, raw)
    spec = ModelSpec.from_dict(config["model"])  # validate early
    multiple = spec.input_multiple
    for key in ("input_size", "val_size"):
        size = config["data"][key]
        if len(size) != 2 or any(int(v) % multiple for v in size):
            raise ValueError(
                f"{path}: data.{key} {size} must be two sides divisible by {multiple} (stride 32 x STFF windows)"
            )
    return config


class ModelEMA:
    """Exponential moving average of the weights (decay ramps up over the first steps)."""

    def __init__(self, model: Detector, decay: float):
        self.ema = copy.deepcopy(model).eval()
        for p in self.ema.parameters():
            p.requires_grad_(False)
        self.decay, self.updates = decay, 0

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        self.updates += 1
        d = self.decay * (1 - math.exp(-self.updates / 200))
        msd = model.state_dict()
        for k, v in self.ema.state_dict().items():
            if v.dtype.is_floating_point:
                v.mul_(d).add_(msd[k].detach(), alpha=1 - d)
            else:
                v.copy_(msd[k])


def spec_for_task(task: str, config: dict[str, Any]) -> ModelSpec:
    """The model spec of ``config``; the local detector is always single-frame without STFF."""
    model = dict(config["model"])
    if task == "local":
        model.update(dual_frame=False, stff_levels=[], stff_windows=[])
    return ModelSpec.from_dict(model)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def build_datasets(
    task: str, config: dict[str, Any]
) -> tuple[GlobalPairDataset | LocalCropDataset, Subset[Any], dict[str, Any]]:
    """Training and validation datasets plus a description of what went in (for the model card)."""
    data = config["data"]
    seed = config["seed"]
    workers = int(data["load_workers"])
    needs_real = data["use_real"] or data["real_validation"]
    split = halmstad_split(data["halmstad_root"]) if needs_real else {"train": [], "val": [], "val_b": []}
    train_pairs, val_pairs = [], []
    if data["use_real"]:
        train_pairs += load_halmstad(
            data["halmstad_root"], split["train"], data["train_frame_step"], data["cache_dir"], workers
        )
    if data["real_validation"]:
        val_pairs += load_halmstad(
            data["halmstad_root"], split["val"], data["val_frame_step"], data["cache_dir"], workers
        )
    synthetic: list = []
    if data["synthetic_scenes"]:
        synthetic = load_synthetic(
            "train",
            data["synthetic_scenes"],
            data["synthetic_frames"],
            data["synthetic_frame_step"],
            data["synthetic_scale"],
            data["cache_dir"],
            workers,
        )
        train_pairs += synthetic
    if data["synthetic_val_scenes"]:
        val_pairs += load_synthetic(
            "val",
            data["synthetic_val_scenes"],
            data["synthetic_frames"],
            data["synthetic_frame_step"] * 2,
            data["synthetic_scale"],
            data["cache_dir"],
            workers,
        )
    if not train_pairs:
        raise ValueError("no training data: use_real is false and no synthetic scenes were produced")
    if not val_pairs:
        raise ValueError("no validation data: real_validation is false and synthetic_val_scenes is 0")
    w, h = data["input_size"]
    copy_paste = _copy_paste(data, train_pairs, seed)
    train_ds: GlobalPairDataset | LocalCropDataset
    val_ds: GlobalPairDataset | LocalCropDataset
    if task == "global":
        train_ds = GlobalPairDataset(train_pairs, (w, h), train=True, seed=seed, copy_paste=copy_paste)
        val_ds = GlobalPairDataset(val_pairs, tuple(data["val_size"]), train=False, seed=seed)
    else:
        train_ds = LocalCropDataset(
            train_pairs,
            w,
            data["roi"],
            train=True,
            seed=seed,
            negative_fraction=data["negative_fraction"],
            copy_paste=copy_paste,
        )
        val_ds = LocalCropDataset(
            val_pairs,
            data["val_size"][0],
            data["val_roi"],
            train=False,
            seed=seed,
            negative_fraction=data["negative_fraction"],
        )
    rng = np.random.default_rng(seed)
    n_val = min(len(val_ds), data["val_max_images"])
    val_subset = Subset(val_ds, sorted(rng.choice(len(val_ds), n_val, replace=False).tolist()))
    train_ds.sample_weights = sample_weights(len(train_pairs) - len(synthetic), len(synthetic), data["synthetic_share"])
    info = {
        "real_train_clips": split["train"] if data["use_real"] else [],
        "real_val_clips": split["val"],
        "real_train_pairs": len(train_pairs) - len(synthetic),
        "synthetic_train_pairs": len(synthetic),
        "synthetic_train_scenes": data["synthetic_scenes"],
        "synthetic_share": data["synthetic_share"],
        "val_pairs_used_per_epoch": n_val,
        "copy_paste": None
        if copy_paste is None
        else {
            "probability": copy_paste.probability,
            "max_objects": copy_paste.max_objects,
            "bank_objects": len(copy_paste.bank),
        },
    }
    return train_ds, val_subset, info


def _copy_paste(data: dict[str, Any], train_pairs: list, seed: int) -> CopyPaste | None:
    """The copy-paste settings of ``data`` with an object bank cut from the training pairs only
    (never from validation clips), or None when ``data.copy_paste`` is 0."""
    probability = float(data["copy_paste"])
    if not 0.0 <= probability <= 1.0:
        raise ValueError(f"data.copy_paste must be a probability within [0, 1], got {data['copy_paste']!r}")
    if probability == 0.0:
        return None
    max_objects, per_class = int(data["copy_paste_max"]), int(data["copy_paste_bank"])
    if max_objects < 1 or per_class < 1:
        raise ValueError(
            f"data.copy_paste_max and data.copy_paste_bank must be >= 1, got {max_objects} and {per_class}"
        )
    return CopyPaste(ObjectBank.from_pairs(train_pairs, per_class=per_class, seed=seed), probability, max_objects)


def sample_weights(num_real: int, num_synthetic: int, synthetic_share: float | None) -> list[float] | None:
    """Per-pair sampling weights (real pairs first) that give the synthetic pairs ``synthetic_share``
    of the draws; ``None`` when every pair is to be equally likely.

    Why: the real clips outnumber the synthetic scenes' pairs about 4 to 1, and a detector trained
    on that mix learns the real drones' look and misses the synthetic ones (issue #6;
    ``docs/experiment-log.md``).
    """
    if synthetic_share is None:
        return None
    share = float(synthetic_share)
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"data.synthetic_share must be within [0, 1], got {synthetic_share!r}")
    if num_synthetic == 0 and share > 0.0:
        raise ValueError(
            f"data.synthetic_share is {share} but no synthetic pairs were loaded (data.synthetic_scenes is 0)"
        )
    if num_real == 0 and share < 1.0:
        raise ValueError(f"data.synthetic_share is {share} but no real pairs were loaded (data.use_real is false)")
    real_weight = (1.0 - share) / num_real if num_real else 0.0
    synthetic_weight = share / num_synthetic if num_synthetic else 0.0
    return [real_weight] * num_real + [synthetic_weight] * num_synthetic


def resolve_device(name: str) -> torch.device:
    """The training device for ``train.device``; asking for CUDA without one is an error, not a silent CPU run."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"train.device is {name!r} but torch {torch.__version__} sees no CUDA device")
    return device


def _run_batch(model: torch.nn.Module, task: str, batch: tuple, device: torch.device) -> tuple[Any, torch.Tensor, Any]:
    """The model on one collated batch, moved to ``device``: ``(output, current images, boxes)``.
    Global batches are ``(previous, current, boxes)`` (collate_pairs), local ones ``(crops, boxes)``
    (collate_crops)."""
    move = lambda t: t.to(device, non_blocking=True)  # noqa: E731
    if task == "global":
        prev, cur, boxes = batch
        prev, cur = move(prev), move(cur)
        return model(prev, cur), cur, [move(b) for b in boxes]
    cur, boxes = batch
    cur = move(cur)
    return model(cur), cur, [move(b) for b in boxes]


@torch.no_grad()
def validate(
    model: torch.nn.Module, task: str, loader: DataLoader, score_threshold: float, device: torch.device | None = None
) -> dict[str, float]:
    """Drone-class AP metrics of ``model`` over ``loader`` (boxes in network-input pixels)."""
    model.eval()
    device = device or next(model.parameters()).device
    dets, gts = [], []
    for batch in loader:
        out, cur, boxes = _run_batch(model, task, batch, device)
        in_h, in_w = cur.shape[2], cur.shape[3]
        for o, b in zip(out.cpu().numpy(), boxes):
            d = decode_output(o, score_threshold, box_scale=(in_w, in_h))
            dets.append(d[d[:, 5] == 0])
            b = b.cpu().numpy()
            gts.append(b[b[:, 0] == 0][:, 1:5])
    return detection_summary(dets, gts)


def plot_curves(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [r["epoch"] for r in rows]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
    for key in ("loss", "box", "cls", "dfl"):
        a1.plot(epochs, [r[key] for r in rows], label=key)
    a1.set_xlabel("epoch"), a1.set_title("training loss"), a1.legend()
    for key in ("val_ap50", "val_ap50_95", "val_pr_auc"):
        a2.plot(epochs, [r[key] for r in rows], label=key)
    a2.set_xlabel("epoch"), a2.set_title("validation (drone)"), a2.legend(), a2.set_ylim(0, 1)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    tmp.replace(path)


def save_checkpoint(
    path: Path, model: torch.nn.Module, spec: ModelSpec, task: str, config: dict[str, Any], extra: dict[str, Any]
) -> None:
    tmp = path.with_suffix(".tmp")
    state = {k: v.detach().cpu() for k, v in model.state_dict().items()}  # loadable on a CPU-only machine
    torch.save({"task": task, "spec": spec.to_dict(), "state_dict": state, "config": config, **extra}, tmp)
    tmp.replace(path)


def load_checkpoint(path: Path | str) -> tuple[Detector, dict[str, Any]]:
    """Rebuild a model from a checkpoint written by :func:`train`; returns (model in eval mode, checkpoint dict)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    model = Detector(ModelSpec.from_dict(ckpt["spec"]))
    model.load_state_dict(ckpt["state_dict"])
    return model.eval(), ckpt


#: The schedule settings a resumed run must share with the run it continues (``train.*``); the
#: optimiser and scheduler state carry them, so a change would be ignored without a word.
RESUME_SCHEDULE_KEYS = ("epochs", "steps_per_epoch", "batch_size", "lr", "weight_decay", "warmup_steps", "ema_decay")


def _checked_network(checkpoint: dict[str, Any], path: Path, task: str, spec: ModelSpec, action: str) -> None:
    """:class:`ResumeError` unless ``checkpoint`` holds a ``task`` detector with ``spec``'s network."""
    if checkpoint.get("task") not in TASKS:
        raise ResumeError(f"cannot {action}: {path} is not a detector checkpoint (written by gldt train global|local)")
    if checkpoint.get("task") != task:
        raise ResumeError(f"cannot {action}: {path} is a {checkpoint.get('task')} checkpoint, this run trains {task}")
    if checkpoint.get("spec") != spec.to_dict():
        raise ResumeError(
            f"cannot {action}: {path} has the network {checkpoint.get('spec')}, the config asks for {spec.to_dict()}"
        )


def _resume_checkpoint(path: Path, task: str, spec: ModelSpec, config: dict[str, Any]) -> dict[str, Any]:
    """The ``last.pt`` at ``path``, checked against this run's task, network and schedule;
    :class:`ResumeError` with one line otherwise."""
    checkpoint = read_checkpoint(path)
    _checked_network(checkpoint, path, task, spec, "resume")
    state = checkpoint.get("resume")
    if not isinstance(state, dict):
        raise ResumeError(f"cannot resume: {path} holds no training state (only last.pt does; best.pt: --init-from)")
    tcfg = config["train"]
    if float(tcfg["max_wall_s"]) > 0:
        raise ResumeError(
            "cannot resume a schedule squeezed into train.max_wall_s (it would restart its clock); "
            "resumable runs count steps: set train.max_wall_s to 0 and end sessions with --stop-after-s"
        )
    theirs = checkpoint.get("config", {}).get("train", {})
    changed = [key for key in RESUME_SCHEDULE_KEYS if theirs.get(key) != tcfg[key]]
    if changed:
        detail = ", ".join(f"{key} {theirs.get(key)} -> {tcfg[key]}" for key in changed)
        raise ResumeError(f"cannot resume: {path} was trained on another schedule ({detail})")
    epoch = checkpoint.get("epoch")
    if isinstance(epoch, int) and epoch >= int(tcfg["epochs"]):
        raise ResumeError(f"cannot resume: {path} finished its schedule (epoch {epoch} of {tcfg['epochs']})")
    return checkpoint


def _initial_weights(path: Path, task: str, spec: ModelSpec) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
    """The (EMA) weights of a finished or stopped run to start a new schedule from, and the training
    seconds by device that went into them."""
    checkpoint = read_checkpoint(path, "start from")
    _checked_network(checkpoint, path, task, spec, "start from")
    spent = checkpoint.get("train_wall_s_by_device")
    if spent is None:  # checkpoints written before the time was kept by device
        device = str(checkpoint.get("config", {}).get("train", {}).get("device", "unknown"))
        spent = {device: float(checkpoint.get("train_wall_s") or 0.0)}
    return checkpoint["state_dict"], dict(spent)


def _best_so_far(out: Path, run_id: str) -> float:
    """AP50 of the ``best.pt`` beside this run's ``last.pt``, if that file is this run's; -1 otherwise
    (a session resumed into another folder keeps its best there from its own epochs on)."""
    path = out / "best.pt"
    if not path.is_file():
        return -1.0
    try:
        best = read_checkpoint(path)
    except ResumeError:  # a torn file is no run's best
        return -1.0
    if best.get("run_id") != run_id:
        return -1.0
    ap50 = best.get("metrics", {}).get("ap50", -1.0)
    return -1.0 if ap50 is None or math.isnan(ap50) else float(ap50)


def train(
    task: str,
    config: dict[str, Any],
    out_dir: Path | None = None,
    progress: bool = True,
    resume: Path | None = None,
    init_from: Path | None = None,
    stop_after_s: float | None = None,
) -> Path:
    """Train one detector; returns the path of ``best.pt``.

    ``resume``: continue the run whose ``last.pt`` this is (weights, EMA, optimiser, schedule,
    epoch and time spent; each epoch's data order and augmentation depend on (seed, epoch) alone).
    ``init_from``: start this config's schedule from another run's weights. ``stop_after_s``:
    end this session at an epoch's end, before an epoch that would end past that many seconds
    (judged by the last epoch's length) or after one that did, to be resumed. A resumed schedule
    counts steps (``train.max_wall_s`` 0) and keeps the settings of :data:`RESUME_SCHEDULE_KEYS`.
    """
    if task not in TASKS:
        raise ValueError(f"task must be one of {TASKS}, got {task!r}")
    if resume is not None and init_from is not None:
        raise ValueError("give --resume (continue a run) or --init-from (start a run from weights), not both")
    from tqdm import tqdm

    seed_everything(config["seed"])
    torch.set_num_threads(int(config["threads"]))
    cv2.setNumThreads(int(config["threads"]))  # the validation's decoding, and augmenting without workers
    spec = spec_for_task(task, config)
    tcfg = config["train"]
    total_steps = tcfg["epochs"] * tcfg["steps_per_epoch"]
    resumed = _resume_checkpoint(Path(resume), task, spec, config) if resume is not None else None
    initial = _initial_weights(Path(init_from), task, spec) if init_from is not None else None
    out = Path(out_dir or config["out_dir"].format(task=task))
    out.mkdir(parents=True, exist_ok=True)
    with (out / "config.yaml").open("w") as fh:
        yaml.safe_dump({"task": task, **config}, fh, sort_keys=False)

    train_ds, val_ds, data_info = build_datasets(task, config)
    collate = collate_pairs if task == "global" else collate_crops
    device = resolve_device(str(tcfg["device"]))
    model = Detector(spec)
    spent: dict[str, float] = {}  # training seconds by device type, over every session of this run
    if initial is not None:
        model.load_state_dict(initial[0])
        spent = initial[1]
        data_info = {**data_info, "initial_weights": str(init_from)}
    model = model.to(device)
    ema = ModelEMA(model, tcfg["ema_decay"])
    criterion = DetectionLoss(spec.num_classes, spec.reg_max, spec.strides).to(device)
    decay: list[torch.nn.Parameter] = []
    no_decay: list[torch.nn.Parameter] = []
    for name, p in model.named_parameters():
        (no_decay if p.ndim <= 1 or name.endswith("alpha") else decay).append(p)
    optimizer = torch.optim.AdamW(
        [{"params": decay, "weight_decay": tcfg["weight_decay"]}, {"params": no_decay, "weight_decay": 0.0}],
        lr=tcfg["lr"],
    )
    max_wall_s = float(tcfg["max_wall_s"])
    step, first_epoch, rows, best = 0, 1, [], -1.0
    run_id = f"{task}-{time.strftime('%Y%m%dT%H%M%S')}-{random.randrange(16**6):06x}"  # ties best.pt to its run
    started = time.time()

    def progress_fraction(steps_done: int) -> float:
        """How far through the schedule: steps done, or wall time spent when that is further."""
        by_time = (time.time() - started) / max_wall_s if max_wall_s > 0 else 0.0
        return min(1.0, max(steps_done / total_steps, by_time))

    def schedule(count: int) -> float:
        """Learning-rate factor after ``count`` scheduler steps (what LambdaLR passes)."""
        return min(1.0, (count + 1) / max(tcfg["warmup_steps"], 1)) * (
            0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * progress_fraction(count)))
        )

    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, schedule)
    if resumed is not None:
        try:
            state = resumed["resume"]
            model.load_state_dict(state["model"])
            ema.ema.load_state_dict(resumed["state_dict"])  # what last.pt saves is the averaged model
            optimizer.load_state_dict(state["optimizer"])
            scheduler.load_state_dict(state["scheduler"])
            ema.updates, step, first_epoch = int(state["ema_updates"]), int(state["step"]), int(resumed["epoch"]) + 1
            rows, spent = list(state["rows"]), dict(resumed["train_wall_s_by_device"])
            run_id = str(state.get("run_id") or run_id)
        except (KeyError, RuntimeError, ValueError, TypeError) as error:
            raise ResumeError(
                f"cannot resume: {resume}: its state does not fit ({type(error).__name__}: {error})"
            ) from None
        best = _best_so_far(out, run_id)
    session_started = time.time()
    spent_before = sum(spent.values())

    def trained_s() -> float:
        """Training time of this run so far, earlier sessions (and --init-from's run) included."""
        return spent_before + time.time() - session_started

    val_loader = DataLoader(val_ds, batch_size=4, shuffle=False, collate_fn=collate)
    workers = int(tcfg["loader_workers"])
    if workers:
        # The loader's workers are forked from this process, and OpenCV's thread pool does not
        # survive a fork: a worker that resizes the copied pool (one_thread_worker) can wait forever
        # on a condition variable of threads that only exist here. The workers do the augmenting,
        # so this process needs no OpenCV threads, and one thread leaves no pool to copy.
        cv2.setNumThreads(1)

    epoch_s = 0.0  # how long the last epoch took, validation included
    for epoch in range(first_epoch, tcfg["epochs"] + 1):
        if stop_after_s is not None and epoch > first_epoch and time.time() - session_started + epoch_s > stop_after_s:
            print(
                f"[{task}] stopped before epoch {epoch}, which would end past --stop-after-s {stop_after_s:.0f}; "
                f"resume with --resume {out / 'last.pt'}",
                flush=True,
            )
            break
        epoch_started = time.time()
        if epoch > first_epoch and progress_fraction(step) >= 1.0:  # a session's first epoch always runs
            print(
                f"[{task}] wall-clock budget of {max_wall_s:.0f} s spent after {epoch - 1} epochs ({step} steps)",
                flush=True,
            )
            break
        train_ds.epoch = epoch  # read by the loader's workers, which start afresh each epoch
        model.train()
        draws = tcfg["steps_per_epoch"] * tcfg["batch_size"]
        weights = train_ds.sample_weights
        generator = torch.Generator().manual_seed(int(config["seed"]) * 1_000_003 + epoch)  # this epoch's data order
        sampler: torch.utils.data.Sampler[int]
        if weights is None:
            sampler = torch.utils.data.RandomSampler(train_ds, replacement=True, num_samples=draws, generator=generator)
        else:
            sampler = torch.utils.data.WeightedRandomSampler(
                weights, num_samples=draws, replacement=True, generator=generator
            )
        loader = DataLoader(
            train_ds,
            batch_size=tcfg["batch_size"],
            sampler=sampler,
            collate_fn=collate,
            num_workers=workers,
            pin_memory=device.type == "cuda",
            prefetch_factor=4 if workers else None,
            worker_init_fn=one_thread_worker,
        )
        sums = {"loss": 0.0, "box": 0.0, "cls": 0.0, "dfl": 0.0}
        batches = 0
        bar = tqdm(loader, desc=f"{task} epoch {epoch}/{tcfg['epochs']}", disable=not progress, dynamic_ncols=True)
        # Where an epoch's time goes: waiting for the loader's batches, or the steps themselves
        # (which end in a device sync, float(loss)), so a run shows which of the two sets its pace.
        data_wait_s = compute_s = 0.0
        fetch_started = time.perf_counter()
        for batch in bar:
            step_started = time.perf_counter()
            data_wait_s += step_started - fetch_started
            maps, cur, boxes = _run_batch(model, task, batch, device)
            loss, parts = criterion(maps, boxes)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            optimizer.step()
            scheduler.step()
            ema.update(model)
            step += 1
            batches += 1
            sums["loss"] += float(loss.detach())
            for k, v in parts.items():
                sums[k] += v
            fetch_started = time.perf_counter()
            compute_s += fetch_started - step_started
            bar.set_postfix(loss=f"{float(loss.detach()):.3f}")
            if progress_fraction(step) >= 1.0:
                break  # the wall-clock budget ends the schedule mid-epoch
            if not progress and step % 10 == 0:
                print(
                    f"[{task}] epoch {epoch} step {step}/{total_steps} loss {float(loss.detach()):.3f} "
                    f"({trained_s():.0f} s)",
                    flush=True,
                )
        n = max(batches, 1)
        metrics = validate(ema.ema, task, val_loader, tcfg["val_score_threshold"], device)
        row = {
            "epoch": epoch,
            **{k: v / n for k, v in sums.items()},
            "lr": optimizer.param_groups[0]["lr"],
            "elapsed_s": round(trained_s(), 1),
            "data_wait_s": round(data_wait_s, 1),
            "compute_s": round(compute_s, 1),
        }
        row.update({f"val_{k}": v for k, v in metrics.items() if k != "num_gt"})
        if task == "global" and spec.stff_levels:
            row["alpha_mean"] = float(np.mean(ema.ema.stff_alphas()))
        rows.append(row)
        with (out / "log.csv").open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(dict.fromkeys(key for r in rows for key in r)))
            writer.writeheader()
            writer.writerows(rows)
        plot_curves(rows, out / "curves.png")
        by_device = add_seconds(spent, device.type, time.time() - session_started)
        extra = {
            "epoch": epoch,
            "metrics": metrics,
            "data": data_info,
            "train_wall_s": round(sum(by_device.values()), 1),
            "train_wall_s_by_device": by_device,
        }
        score = metrics["ap50"] if not math.isnan(metrics["ap50"]) else 0.0
        improved = score > best
        best = max(best, score)
        resume_state = {
            "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
            "ema_updates": ema.updates,
            "optimizer": _to_cpu(optimizer.state_dict()),
            "scheduler": scheduler.state_dict(),
            "step": step,
            "rows": rows,
            "run_id": run_id,
        }  # the epoch and the time by device are the checkpoint's own fields; the best is best.pt's
        save_checkpoint(out / "last.pt", ema.ema, spec, task, config, {**extra, "resume": resume_state})
        if improved:
            save_checkpoint(out / "best.pt", ema.ema, spec, task, config, {**extra, "run_id": run_id})
        print(
            f"[{task}] epoch {epoch}: loss {row['loss']:.3f} val AP50 {metrics['ap50']:.3f} "
            f"AP50:95 {metrics['ap50_95']:.3f} ({row['elapsed_s']} s; waited {data_wait_s:.0f} s for batches, "
            f"stepped {compute_s:.0f} s)",
            flush=True,
        )
        epoch_s = time.time() - epoch_started
        if stop_after_s is not None and time.time() - session_started >= stop_after_s and epoch < tcfg["epochs"]:
            print(
                f"[{task}] stopped after epoch {epoch} (--stop-after-s); resume with --resume {out / 'last.pt'}",
                flush=True,
            )
            break
    return out / "best.pt"


def one_thread_worker(_worker_id: int) -> None:
    """A loader worker is one core's worth of decoding and augmenting: OpenCV's own thread pool
    (as many threads as the machine has cores, whatever OMP_NUM_THREADS says) would otherwise
    start in every worker and oversubscribe the cores (16 workers x 16 threads on a GPU machine)."""
    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def _to_cpu(value: Any) -> Any:
    """``value`` (an optimiser state) with every tensor moved to the CPU, so a GPU run resumes anywhere."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: _to_cpu(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_to_cpu(v) for v in value]
    return value
