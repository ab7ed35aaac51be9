"""``make demo`` says why a bag gave no tracks instead of leaving an empty result unexplained."""

from __future__ import annotations

from pathlib import Path

import pytest

from gldt_core.cli import demo


@pytest.mark.parametrize(
    "bag_name, rows, note",
    [
        ("synth_1080p_multi_uav", "", demo.NO_TRACKS_NOTE),
        ("halmstad_v_drone_001", "", demo.NO_TRACKS_ELSEWHERE),
        ("synth_1080p_multi_uav", "1,1,10,10,5,5,0.9,-1,-1,-1\n", None),
    ],
)
def test_an_empty_track_file_is_explained(
    tmp_path: Path, monkeypatch, capsys, bag_name: str, rows: str, note: str | None
) -> None:
    def fake_run(bag: Path, out: Path) -> Path:
        tracks = out / "tracks.txt"
        tracks.write_text(rows)
        return tracks

    monkeypatch.setattr(demo, "run_offline", fake_run)
    bag = tmp_path / bag_name
    bag.mkdir()
    assert demo.main(["--no-ros", "--bag", str(bag), "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    notes = [text for text in (demo.NO_TRACKS_NOTE, demo.NO_TRACKS_ELSEWHERE) if text in printed]
    assert notes == ([note] if note else [])
