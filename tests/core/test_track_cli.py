"""``gldt track`` and ``gldt eval`` end to end on files written here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gldt_core.cli import main
from gldt_core.eval.streams import StreamParams, detections_from_gt, simple_multi_target_gt
from gldt_core.io.mot import read_mot, write_mot


def _scene(tmp_path: Path, seed: int = 0, frames: int = 90) -> tuple[Path, Path]:
    gt = simple_multi_target_gt(seed, frames, size=(1280, 720), targets=3)
    gt[:, 4:6] = np.maximum(gt[:, 4:6], 60.0)  # comfortable sizes: this test is about the plumbing
    clean = StreamParams(burst_rate=0.0, miss_rate=0.0, low_score_rate=0.0, jitter_frac=0.01, fp_rate=0.0)
    dets = detections_from_gt(gt, seed, (1280, 720), clean)
    gt_path, det_path = tmp_path / "gt.txt", tmp_path / "det.txt"
    write_mot(gt_path, gt)
    write_mot(det_path, dets)
    return gt_path, det_path


@pytest.mark.parametrize("tracker", ["jptrack", "bytetrack"])
def test_track_then_eval_json(tmp_path: Path, capsys, tracker: str) -> None:
    gt_path, det_path = _scene(tmp_path)
    out_path = tmp_path / "tracks.txt"
    assert main(["track", "--dets", str(det_path), "--out", str(out_path), "--tracker", tracker, "--fps", "30"]) == 0
    tracks = read_mot(out_path)
    assert len(tracks) > 200
    assert set(np.unique(tracks[:, 7:10])) == {-1.0}
    capsys.readouterr()
    assert main(["eval", "--gt", str(gt_path), "--pred", str(out_path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    combined = result["combined"]
    for key in ("HOTA", "DetA", "AssA", "MOTA", "MOTP", "IDF1", "IDSW", "FP", "FN", "Frag"):
        assert key in combined
    assert combined["MOTA"] > 0.8 and combined["IDF1"] > 0.7 and combined["IDSW"] <= 3


def test_eval_folders_and_table(tmp_path: Path, capsys) -> None:
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    for seed in (1, 2):
        gt_path, det_path = _scene(tmp_path, seed, frames=40)
        (gt_dir / f"seq{seed}" / "gt").mkdir(parents=True)
        gt_path.rename(gt_dir / f"seq{seed}" / "gt" / "gt.txt")
        pred_dir.mkdir(exist_ok=True)
        assert main(["track", "--dets", str(det_path), "--out", str(pred_dir / f"seq{seed}.txt")]) == 0
    capsys.readouterr()
    assert main(["eval", "--gt", str(gt_dir), "--pred", str(pred_dir)]) == 0
    table = capsys.readouterr().out
    assert "seq1" in table and "seq2" in table and "COMBINED" in table and "HOTA" in table


def test_missing_prediction_for_a_sequence_is_named(tmp_path: Path, capsys) -> None:
    (tmp_path / "gt").mkdir()
    (tmp_path / "pred").mkdir()
    (tmp_path / "gt" / "seqA.txt").write_text("1,1,10,10,5,5,1,1,1\n")
    assert main(["eval", "--gt", str(tmp_path / "gt"), "--pred", str(tmp_path / "pred")]) == 2
    assert "seqA" in capsys.readouterr().err


def test_malformed_detection_line_names_file_and_line(tmp_path: Path, capsys) -> None:
    det = tmp_path / "det.txt"
    det.write_text("1,-1,10,10,20,20,0.9\n2,-1,abc,10,20,20,0.9\n")
    assert main(["track", "--dets", str(det), "--out", str(tmp_path / "o.txt")]) == 2
    err = capsys.readouterr().err
    assert f"{det}:2" in err
    assert not (tmp_path / "o.txt").exists()


def test_score_out_of_range_names_file_frame_and_field(tmp_path: Path, capsys) -> None:
    det = tmp_path / "det.txt"
    det.write_text("1,-1,10,10,20,20,0.9\n3,-1,10,10,20,20,1.7\n")
    assert main(["track", "--dets", str(det), "--out", str(tmp_path / "o.txt")]) == 2
    err = capsys.readouterr().err
    assert str(det) in err and "frame 3" in err and "score" in err
    assert not (tmp_path / "o.txt").exists()


def test_bad_fps_is_refused(tmp_path: Path, capsys) -> None:
    det = tmp_path / "det.txt"
    det.write_text("1,-1,10,10,20,20,0.9\n")
    assert main(["track", "--dets", str(det), "--out", str(tmp_path / "o.txt"), "--fps", "0"]) == 2
    assert "--fps" in capsys.readouterr().err


def test_empty_frames_in_the_middle_coast_with_time(tmp_path: Path) -> None:
    """Frames 11-30 have no detection lines at all: the tracker still sees 0.67 s pass."""
    rows = []
    for f in list(range(1, 11)) + list(range(31, 41)):
        x = 100.0 + 3.0 * f
        rows.append([f, -1, x, 200.0, 20.0, 14.0, 0.9, -1, -1, -1])
    det = tmp_path / "det.txt"
    write_mot(det, np.asarray(rows))
    assert main(["track", "--dets", str(det), "--out", str(tmp_path / "o.txt")]) == 0
    tracks = read_mot(tmp_path / "o.txt")
    assert set(tracks[:, 1].astype(int).tolist()) == {1}
    assert tracks[:, 0].max() == 40


def test_a_frame_number_far_beyond_the_rest_costs_no_memory(tmp_path: Path) -> None:
    """One row at frame 100,000,000 (a typo, a counter that wrapped): `gldt track` and `gldt eval`
    answer in bounded memory and time, as if the gap were not there. Run under a 1 GiB address
    space limit, where sizing anything by the frame number (800 MB per int64 array) fails."""
    import subprocess
    import sys

    gt_path, det_path = _scene(tmp_path, frames=60)
    far = "100000000,-1,100,100,20,12,0.9,-1,-1,-1\n"
    for path in (gt_path, det_path):
        path.write_text(path.read_text() + far.replace(",0.9,", ",1,") if path == gt_path else path.read_text() + far)
    out_path = tmp_path / "tracks.txt"
    script = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))\n"
        "from gldt_core.cli import main\n"
        f"assert main(['track', '--dets', {str(det_path)!r}, '--out', {str(out_path)!r}, '--fps', '30']) == 0\n"
        f"sys.exit(main(['eval', '--gt', {str(gt_path)!r}, '--pred', {str(out_path)!r}, '--json']))\n"
    )
    completed = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr[-2000:]
    result = json.loads(completed.stdout[completed.stdout.index("{") :])
    assert result["combined"]["FN"] >= 1  # the far ground-truth row was evaluated, not dropped
    assert len(read_mot(out_path)) > 100
