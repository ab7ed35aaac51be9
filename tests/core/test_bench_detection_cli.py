"""`gldt bench detection`: a small run writes its report, and the global input size can be set."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gldt_core.cli import main


def test_a_small_run_at_a_larger_global_input_writes_its_report(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "bench",
            "detection",
            "--real-root",
            str(tmp_path / "no-clips"),
            "--synthetic-scenes",
            "1",
            "--synthetic-frames",
            "4",
            "--long-side",
            "1280",
            "--latency-runs",
            "1",
            "--latency-threads",
            "1",
            "--out",
            str(tmp_path / "out"),
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "skipping the real-data rows" in out
    assert "global input 1280x768" in out, "--long-side must reach the global models"
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    rows = report["datasets"]["synthetic-test"]
    assert set(rows) == {"AM-YOLO+2nd", "AM-YOLO", "no-STFF", "local+2nd", "local", "fused+2nd"}
    assert report["operating_thresholds"]["fused+2nd"] == report["operating_thresholds"]["AM-YOLO+2nd"]
    for key in ("num_gt", "ap50"):
        assert key in rows["fused+2nd"]
    assert (tmp_path / "out" / "pr_synthetic-test.png").is_file()


def test_cards_are_not_updated_from_a_run_at_another_input_size(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["bench", "detection", "--long-side", "1280", "--update-cards", "--out", str(tmp_path)])
    assert code == 2
    assert "--update-cards" in capsys.readouterr().err


def test_false_drones_are_counted_per_clip_and_listed_most_first() -> None:
    from gldt_core.bench.detection import _counts_by_clip, clips_most_first

    counts = [0, 2, 1, 0, 0, 3, 0, 1, 1]
    by_clip = _counts_by_clip(counts, {"V_BIRD_004": 3, "V_AIRPLANE_019": 2, "V_AIRPLANE_049": 4})
    assert by_clip == {"V_BIRD_004": 3, "V_AIRPLANE_019": 0, "V_AIRPLANE_049": 5}
    assert clips_most_first(by_clip) == "V_AIRPLANE_049 5, V_BIRD_004 3"
    assert clips_most_first({"V_BIRD_004": 0}) == ""
    with pytest.raises(ValueError, match="^9 frame counts for 8 frames$"):
        _counts_by_clip(counts, {"V_BIRD_004": 8})
