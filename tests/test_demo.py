"""``make demo`` says why a bag gave no tracks instead of leaving an empty result unexplained."""

from __future__ import annotations

from pathlib import Path

import pytest

from gldt_core import demo


@pytest.mark.parametrize("rows, noted", [("", True), ("1,1,10,10,5,5,0.9,-1,-1,-1\n", False)])
def test_an_empty_track_file_is_explained(tmp_path: Path, monkeypatch, capsys, rows: str, noted: bool) -> None:
    def fake_run(bag: Path, out: Path) -> Path:
        tracks = out / "tracks.txt"
        tracks.write_text(rows)
        return tracks

    monkeypatch.setattr(demo, "run_offline", fake_run)
    bag = tmp_path / "some_bag"
    bag.mkdir()
    assert demo.main(["--no-ros", "--bag", str(bag), "--out", str(tmp_path / "out")]) == 0
    assert (demo.NO_TRACKS_NOTE in capsys.readouterr().out) is noted
