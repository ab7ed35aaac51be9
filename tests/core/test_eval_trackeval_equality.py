"""gldt_core.eval must give TrackEval 1.3.0's numbers (to 1e-6) on awkward sequences.

TrackEval is run for real through its MotChallenge2DBox dataset on files written to tmp_path. Our
drone classes are mapped onto TrackEval's MOT17 classes so that its preprocessing does what ours
documents: drone -> pedestrian (1), bird/airplane/helicopter -> distractor (8), anything else ->
car (3, ignored but not a distractor).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from gldt_core.eval import evaluate_many, evaluate_sequence

trackeval = pytest.importorskip("trackeval", reason="TrackEval is the reference implementation")

FLOAT_KEYS = (
    "HOTA",
    "DetA",
    "AssA",
    "DetRe",
    "DetPr",
    "AssRe",
    "AssPr",
    "LocA",
    "MOTA",
    "MOTP",
    "MODA",
    "IDF1",
    "IDP",
    "IDR",
)
COUNT_KEYS = {
    "IDSW": "IDSW",
    "FP": "CLR_FP",
    "FN": "CLR_FN",
    "TP": "CLR_TP",
    "Frag": "Frag",
    "MT": "MT",
    "PT": "PT",
    "ML": "ML",
    "IDTP": "IDTP",
    "IDFP": "IDFP",
    "IDFN": "IDFN",
}


def _trackeval_class(c: float) -> int:
    if c in (1, -1):
        return 1
    if c in (2, 3, 4):
        return 8
    return 3


def _write(path: Path, rows: np.ndarray, gt: bool) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as handle:
        for r in np.asarray(rows, dtype=float).tolist():
            if gt:
                cls = _trackeval_class(r[7])
                handle.write(f"{int(r[0])},{int(r[1])},{r[2]!r},{r[3]!r},{r[4]!r},{r[5]!r},{int(r[6])},{cls},1\n")
            else:
                handle.write(f"{int(r[0])},{int(r[1])},{r[2]!r},{r[3]!r},{r[4]!r},{r[5]!r},{r[6]!r},-1,-1,-1\n")


def run_trackeval(tmp: Path, sequences: dict[str, tuple[np.ndarray, np.ndarray, int]]) -> dict:
    """Run TrackEval on {seq: (gt, pred, length)}; return its per-sequence and combined results."""
    gt_root = tmp / "gt"
    tr_root = tmp / "trackers"
    for name, (gt, pred, length) in sequences.items():
        seq_dir = gt_root / name
        _write(seq_dir / "gt" / "gt.txt", gt, gt=True)
        (seq_dir / "seqinfo.ini").write_text(f"[Sequence]\nname={name}\nseqLength={length}\n")
        _write(tr_root / "tracker" / "data" / f"{name}.txt", pred, gt=False)
    dataset_config = {
        "GT_FOLDER": str(gt_root),
        "TRACKERS_FOLDER": str(tr_root),
        "OUTPUT_FOLDER": str(tmp / "out"),
        "TRACKERS_TO_EVAL": ["tracker"],
        "BENCHMARK": "MOT17",
        "SPLIT_TO_EVAL": "train",
        "SKIP_SPLIT_FOL": True,
        "PRINT_CONFIG": False,
        "SEQ_INFO": {name: length for name, (_, _, length) in sequences.items()},
    }
    eval_config = {
        "USE_PARALLEL": False,
        "PRINT_RESULTS": False,
        "PRINT_ONLY_COMBINED": False,
        "PRINT_CONFIG": False,
        "TIME_PROGRESS": False,
        "DISPLAY_LESS_PROGRESS": True,
        "OUTPUT_SUMMARY": False,
        "OUTPUT_EMPTY_CLASSES": False,
        "OUTPUT_DETAILED": False,
        "PLOT_CURVES": False,
        "BREAK_ON_ERROR": True,
        "RETURN_ON_ERROR": False,
        "LOG_ON_ERROR": str(tmp / "error.log"),
    }
    metric_config = {"THRESHOLD": 0.5, "PRINT_CONFIG": False}
    evaluator = trackeval.Evaluator(eval_config)
    dataset = trackeval.datasets.MotChallenge2DBox(dataset_config)
    metrics = [
        trackeval.metrics.HOTA(),
        trackeval.metrics.CLEAR(metric_config),
        trackeval.metrics.Identity(metric_config),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        results, _ = evaluator.evaluate([dataset], metrics)
    per_seq = results["MotChallenge2DBox"]["tracker"]
    return {name: _flatten(per_seq[name]["pedestrian"]) for name in per_seq}


def _flatten(res: dict) -> dict:
    out = {}
    for key in ("HOTA", "DetA", "AssA", "DetRe", "DetPr", "AssRe", "AssPr", "LocA"):
        out[key] = float(np.mean(res["HOTA"][key]))
    for key in ("MOTA", "MOTP", "MODA"):
        out[key] = float(res["CLEAR"][key])
    for key in ("IDF1", "IDP", "IDR"):
        out[key] = float(res["Identity"][key])
    for ours, theirs in COUNT_KEYS.items():
        source = res["Identity"] if theirs.startswith("ID") and theirs != "IDSW" else res["CLEAR"]
        out[ours] = int(source[theirs])
    return out


def _assert_equal(ours: dict, reference: dict, label: str) -> None:
    for key in FLOAT_KEYS:
        assert ours[key] == pytest.approx(reference[key], abs=1e-6), f"{label}: {key}"
    for key in COUNT_KEYS:
        assert ours[key] == reference[key], f"{label}: {key}"


def random_sequence(seed: int, frames: int = 60, objects: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Moving gt boxes (drones plus a bird and a zero-confidence drone) and a noisy tracker output
    with misses, false positives, id switches and id reuse across objects."""
    rng = np.random.default_rng(seed)
    gt_rows, pred_rows = [], []
    next_pred_id = 1
    for obj in range(objects + 2):
        cls = 2 if obj == objects else 1
        considered = 0 if obj == objects + 1 else 1
        start = int(rng.integers(1, frames // 3))
        stop = int(rng.integers(2 * frames // 3, frames + 1))
        pos = rng.uniform(20, 300, size=2)
        vel = rng.normal(0, 3, size=2)
        size = rng.uniform(12, 40, size=2)
        pred_id = next_pred_id
        next_pred_id += 1
        for f in range(start, stop + 1):
            pos = pos + vel
            if rng.random() < 0.1:
                continue  # gt gap: object not annotated (occluded)
            gt_rows.append([f, obj + 1, *pos, *size, considered, cls, 1, -1])
            if rng.random() < 0.15:
                continue  # tracker miss
            if rng.random() < 0.05:
                pred_id = next_pred_id  # id switch
                next_pred_id += 1
            if rng.random() < 0.03:
                pred_id = 1 + (pred_id % 3)  # id reused from another object
            jitter = rng.normal(0, 2.0, size=2)
            pred_rows.append([f, pred_id, *(pos + jitter), *(size * rng.uniform(0.8, 1.2, 2)), 0.9, -1, -1, -1])
        # false positives
    for f in range(1, frames + 1):
        if rng.random() < 0.2:
            pred_rows.append([f, 900 + int(rng.integers(0, 3)), *rng.uniform(0, 300, 2), 20, 20, 0.4, -1, -1, -1])
    gt = np.asarray(gt_rows, dtype=float)
    pred = np.asarray(pred_rows, dtype=float)
    # A prediction may not repeat an id in one frame (TrackEval refuses it): keep the first.
    keys = pred[:, 0] * 10000 + pred[:, 1]
    _, first = np.unique(keys, return_index=True)
    pred = pred[np.sort(first)]
    return gt, pred


def _cases() -> dict[str, tuple[np.ndarray, np.ndarray, int]]:
    cases: dict[str, tuple[np.ndarray, np.ndarray, int]] = {}
    for seed in range(4):
        gt, pred = random_sequence(seed)
        cases[f"random{seed}"] = (gt, pred, 64)  # frames 61-64 are empty at the end
    gt, _ = random_sequence(10)
    cases["no_predictions"] = (gt, np.zeros((0, 10)), 64)
    far = gt.copy()
    far[:, 2] += 5000.0
    far[:, 6] = 0.9
    far[:, 7:] = -1
    cases["no_matches"] = (gt, far, 64)
    _, pred = random_sequence(11)
    cases["only_false_positives"] = (np.zeros((0, 10)), pred, 64)
    # One object, one tracker id that leaves and comes back on a different object (id reuse),
    # with an empty middle section.
    rows_gt, rows_pr = [], []
    for f in range(1, 21):
        rows_gt.append([f, 1, 10 + f, 10, 20, 20, 1, 1, 1, -1])
        rows_pr.append([f, 7, 10 + f, 11, 20, 20, 0.9, -1, -1, -1])
    for f in range(31, 51):
        rows_gt.append([f, 2, 200 - f, 50, 20, 20, 1, 1, 1, -1])
        rows_pr.append([f, 7, 200 - f, 49, 20, 20, 0.9, -1, -1, -1])
    cases["id_reuse_gap"] = (np.asarray(rows_gt, float), np.asarray(rows_pr, float), 55)
    return cases


def test_every_case_equals_trackeval_per_sequence_and_combined(tmp_path: Path) -> None:
    cases = _cases()
    reference = run_trackeval(tmp_path, cases)
    for name, (gt, pred, length) in cases.items():
        ours = evaluate_sequence(gt, pred, num_frames=length)
        _assert_equal(ours, reference[name], name)
    combined = evaluate_many({name: (gt, pred) for name, (gt, pred, _) in cases.items()})
    _assert_equal(combined["combined"], reference["COMBINED_SEQ"], "COMBINED_SEQ")


def test_metrics_are_not_trivial_on_the_random_cases() -> None:
    """Guards the equality test: the cases must exercise switches, misses and false positives."""
    gt, pred = random_sequence(0)
    res = evaluate_sequence(gt, pred)
    assert res["IDSW"] > 0 and res["FP"] > 0 and res["FN"] > 0
    assert 0.2 < res["HOTA"] < 0.95


def test_perfect_tracking_scores_one_and_bird_following_is_not_a_false_positive() -> None:
    gt, _ = random_sequence(3)
    pred = gt[(gt[:, 6] != 0)].copy()  # exact copy of every considered row, including the bird
    pred[:, 7:] = -1
    res = evaluate_sequence(gt, pred)
    assert res["HOTA"] == pytest.approx(1.0)
    assert res["MOTA"] == pytest.approx(1.0)
    assert res["IDF1"] == pytest.approx(1.0)
    assert res["FP"] == 0 and res["IDSW"] == 0


def test_duplicate_prediction_id_in_a_frame_is_a_clear_error() -> None:
    gt = np.array([[1, 1, 0, 0, 10, 10, 1, 1, 1, -1]], float)
    pred = np.array([[1, 3, 0, 0, 10, 10, 1, -1, -1, -1], [1, 3, 5, 5, 10, 10, 1, -1, -1, -1]], float)
    with pytest.raises(ValueError, match="frame 1"):
        evaluate_sequence(gt, pred)


def test_non_finite_box_is_a_clear_error() -> None:
    pred = np.array([[4, 3, np.nan, 0, 10, 10, 1, -1, -1, -1]], float)
    with pytest.raises(ValueError, match="frame 4"):
        evaluate_sequence(np.zeros((0, 10)), pred)
