"""``gldt bench soak`` (the long run itself is a benchmark, not a test): a seconds-long run proves
the accounting - delivered = processed + dropped, memory sampled, JSON written atomically - and the
ping-pong loop keeps scene motion continuous."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gldt_core.bench.soak import ping_pong
from gldt_core.cli import main


@pytest.mark.parametrize("n", [2, 3, 7, 90])
def test_ping_pong_visits_every_scene_frame_with_unit_steps(n: int) -> None:
    shown = [ping_pong(k, n) for k in range(5 * n)]
    assert shown[:n] == list(range(n))
    assert set(shown) == set(range(n))
    assert all(abs(b - a) == 1 for a, b in zip(shown, shown[1:])), "the loop jumps: motion would teleport"


def test_short_soak_accounts_for_every_frame_and_writes_json(tmp_path: Path, capsys) -> None:
    out = tmp_path / "soak.json"
    code = main(
        [
            "bench",
            "soak",
            "--minutes",
            "0.03",
            "--fps",
            "30",
            "--loop-frames",
            "8",
            "--size",
            "320x240",
            "--targets",
            "2",
            "--detector",
            "oracle",
            "--sample-every",
            "0.5",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    text = capsys.readouterr().out
    assert "RSS:" in text and "track table:" in text and "dropped" in text
    report = json.loads(out.read_text())
    assert report["frames_processed"] >= 1
    assert report["frames_processed"] + report["frames_dropped"] == report["frames_delivered"]
    assert report["frames_delivered"] >= int(0.03 * 60 * 30)
    assert report["rss_start_bytes"] > 0 and report["rss_end_bytes"] > 0
    assert len(report["rss_samples"]) >= 2
    assert report["tracks_at_end"] <= report["max_tracks"] <= 10
    assert report["reinitialisations"] == 0
    assert not list(tmp_path.glob(".*partial"))


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--minutes", "0"], "--minutes"),
        (["--fps", "-5"], "--fps"),
        (["--loop-frames", "1"], "--loop-frames"),
    ],
)
def test_bad_soak_arguments_are_one_line_errors(capsys, argv: list[str], needle: str) -> None:
    code = main(["bench", "soak", "--detector", "oracle", *argv])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and needle in err
