"""``gldt bench tracking --quick`` runs end to end and reports every tracker (slow: a benchmark)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gldt_core.cli import main


@pytest.mark.slow
def test_quick_benchmark_reports_all_our_trackers(tmp_path: Path, capsys) -> None:
    out = tmp_path / "bench.json"
    assert main(["bench", "tracking", "--quick", "--no-peers", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "IDSW" in text and "update time per frame" in text and "peers skipped" in text
    payload = json.loads(out.read_text())
    for name in ("ByteTrack (ours)", "JPTrack JCMA", "JPTrack JCMA+PMR"):
        assert name in payload["accuracy"]
        assert payload["speed"]["3"][name]["mean_ms"] > 0
        assert payload["speed"]["50"][name]["p99_ms"] >= payload["speed"]["50"][name]["mean_ms"] * 0.5
    assert any("IDSW JPTrack/ByteTrack" in line for line in payload["targets"])
