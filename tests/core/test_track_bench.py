"""``gldt bench tracking``: profiles, the worst-profile headline, targets, and a quick run end to end."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from gldt_core.bench import tracking
from gldt_core.cli import main
from gldt_core.eval.id_events import RECOVERY_OTHER, SWAP, IdSwitchEvent
from gldt_core.eval.streams import PROFILES, StreamSequence


def test_profiles_option_selects_in_order_and_refuses_unknown_names() -> None:
    everything = tracking.select_profiles(None)
    assert everything == [p.name for p in PROFILES] + list(tracking.REAL_PROFILES)
    assert tracking.select_profiles("real-detector-val_b, crossing") == ["crossing", "real-detector-val_b"]
    with pytest.raises(ValueError, match="known"):
        tracking.select_profiles("crossing,bogus")
    with pytest.raises(ValueError):
        tracking.select_profiles(" , ")


@pytest.mark.parametrize("fps", [15.0, 60.0])
def test_trackers_get_the_time_of_the_sequences_own_frame_rate(fps: float) -> None:
    seen: dict = {"t": [], "made": None}

    class Recorder:
        tracks: list = [1]  # never "empty": every frame is an update

        def update(self, dets: np.ndarray, t: float) -> np.ndarray:
            seen["t"].append(t)
            return np.zeros((0, 6))

    def make(size: tuple[int, int], rate: float) -> Recorder:
        seen["made"] = (size, rate)
        return Recorder()

    dets = np.array([[1, -1, 10, 10, 5, 5, 0.9, -1, -1, -1]], dtype=float)
    sequence = StreamSequence("s", np.zeros((0, 10)), dets, fps, (640, 480), 9)
    tracking._track(make, sequence)
    assert seen["made"] == ((640, 480), fps)
    np.testing.assert_allclose(seen["t"], np.arange(9) / fps)


def _metrics(hota: float, idf1: float, idsw: int) -> dict:
    return {"HOTA": hota, "IDF1": idf1, "IDSW": idsw}


def test_the_headline_is_each_trackers_worst_profile_not_its_mean() -> None:
    results = {
        "a": {"JPTrack JCMA+PMR": _metrics(0.9, 0.9, 1), "ByteTrack (ours)": _metrics(0.5, 0.6, 10)},
        "b": {"JPTrack JCMA+PMR": _metrics(0.3, 0.8, 2), "ByteTrack (ours)": _metrics(0.6, 0.4, 12)},
        "c": {"JPTrack JCMA+PMR": _metrics(0.5, 0.5, 3), "ByteTrack (ours)": _metrics(0.7, 0.7, 14)},
    }
    worst = tracking.worst_profiles(results, {"a": "tuning", "b": "tuning", "c": "held-out"})
    assert worst["JPTrack JCMA+PMR"]["all_HOTA"] == {"profile": "b", "value": 0.3}
    assert worst["JPTrack JCMA+PMR"]["all_IDF1"] == {"profile": "c", "value": 0.5}
    assert worst["ByteTrack (ours)"]["all_IDF1"] == {"profile": "b", "value": 0.4}
    assert worst["JPTrack JCMA+PMR"]["held_out_HOTA"] == {"profile": "c", "value": 0.5}


def test_targets_are_marked_per_profile_and_on_the_worst_profile() -> None:
    diou, ours, jp = tracking.DIOU_PEER, tracking.OURS_BYTETRACK, tracking.JPTRACK_FULL
    results = {
        "easy": {jp: _metrics(0.60, 0.70, 4), diou: _metrics(0.55, 0.65, 5), ours: _metrics(0.4, 0.5, 10)},
        "hard": {jp: _metrics(0.30, 0.40, 9), diou: _metrics(0.35, 0.38, 8), ours: _metrics(0.2, 0.35, 12)},
    }
    worst = tracking.worst_profiles(results, {"easy": "tuning", "hard": "held-out"})
    speed = {
        3: {jp: {"mean_ms": 0.2}, ours: {"mean_ms": 0.1}},
        50: {jp: {"mean_ms": 2.0}, ours: {"mean_ms": 1.0}},
    }
    lines = tracking.target_lines(results, worst, speed)
    easy = [line for line in lines if line.startswith("[easy]")]
    hard = [line for line in lines if line.startswith("[hard]")]
    assert "MISSED" not in easy[0] and easy[0].count("OK") == 3  # HOTA, IDF1 above DIoU; IDSW no higher
    assert "IDSW 4/10 = 0.40 (<= 0.50: OK)" in easy[1] and "+20.00 points (>= +10: OK)" in easy[1]
    assert "HOTA 30.00 vs 35.00 (MISSED)" in hard[0] and "IDF1 40.00 vs 38.00 (OK)" in hard[0]
    assert "IDSW 9 vs 8 (MISSED)" in hard[0]
    assert "0.75 (<= 0.50: MISSED)" in hard[1] and "+5.00 points (>= +10: MISSED)" in hard[1]
    worst_lines = [line for line in lines if line.startswith("[worst profile]")]
    assert "HOTA: JPTrack 30.00 (hard) vs ByteTrack+DIoU 35.00 (hard) (MISSED)" in worst_lines[0]
    assert "IDF1: JPTrack 40.00 (hard) vs ByteTrack+DIoU 38.00 (hard) (OK)" in worst_lines[1]
    assert any("[speed 3 targets]" in line and "2.00x" in line for line in lines)
    assert "per 1000 matched boxes" not in easy[1]  # no TP counts given


def test_identity_switches_are_also_read_per_matched_box_against_our_bytetrack() -> None:
    diou, ours, jp = tracking.DIOU_PEER, tracking.OURS_BYTETRACK, tracking.JPTRACK_FULL
    few = {"HOTA": 0.03, "IDF1": 0.04, "IDSW": 22, "TP": 176}  # keeps almost no track
    many = {"HOTA": 0.25, "IDF1": 0.40, "IDSW": 33, "TP": 2492}
    results = {"sparse": {jp: many, diou: {**many, "IDSW": 45}, ours: few}}
    worst = tracking.worst_profiles(results, {"sparse": "held-out"})
    speed = {3: {jp: {"mean_ms": 0.2}, ours: {"mean_ms": 0.1}}}
    line = [x for x in tracking.target_lines(results, worst, speed) if "vs our ByteTrack" in x][0]
    # The target stays the raw count (missed); the normalised figures are context.
    assert "IDSW 33/22 = 1.50 (<= 0.50: MISSED; per 1000 matched boxes 13.2 vs 125.0)" in line


def test_a_one_profile_run_reports_it_with_its_role(capsys) -> None:
    args = ["bench", "tracking", "--profiles", "occlusion-15hz", "--sequences", "1", "--seconds", "2"]
    assert main(args + ["--no-peers", "--speed-frames", "4"]) == 0
    text = capsys.readouterr().out
    assert "occlusion-15hz [HELD OUT]" in text and "30 frames at 15 Hz" in text
    assert "[ours" not in text and "worst profile per tracker" in text
    assert "[occlusion-15hz] vs our ByteTrack" in text and "not run (boxmot peers missing or skipped)" in text


def test_sequence_margins_count_the_sequences_a_tracker_loses_and_name_its_worst() -> None:
    def seq(hota: float, idf1: float) -> dict:
        return {"HOTA": hota, "IDF1": idf1, "MOTA": 0.5, "IDSW": 0}

    per_sequence = {
        "a": {
            "J": {"s1": seq(0.6, 0.7), "s2": seq(0.4, 0.5), "s3": seq(0.5, 0.9)},
            "P": {"s1": seq(0.5, 0.6), "s2": seq(0.45, 0.8), "s3": seq(0.5, 0.8)},
        },
        "b": {"J": {"s1": seq(0.6, 0.7)}},  # the peer did not run here
    }
    margins = tracking.sequence_margins(per_sequence, "J", "P")
    assert list(margins) == ["a"]
    a = margins["a"]
    assert a["sequences"] == 3 and a["behind_HOTA"] == 1 and a["behind_IDF1"] == 1
    assert a["worst_HOTA"]["sequence"] == "s2" and a["worst_HOTA"]["margin"] == pytest.approx(-0.05)
    assert a["worst_IDF1"] == {"sequence": "s2", "margin": pytest.approx(-0.3)}


@pytest.mark.slow
def test_quick_benchmark_reports_every_profile_tracker_and_the_worst_profile(
    tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("GLDT_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "bench.json"
    assert main(["bench", "tracking", "--quick", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    payload = json.loads(out.read_text())
    ours = ("ByteTrack (ours)", "JPTrack JCMA", "JPTrack JCMA+PMR")
    has_boxmot = importlib.util.find_spec("boxmot") is not None
    peers = ("boxmot ByteTrack (IoU)", "boxmot ByteTrack (DIoU)", "boxmot OC-SORT", "boxmot BoT-SORT (no ReID)")
    trackers = ours + (peers if has_boxmot else ())
    real_ran = [name for name in tracking.REAL_PROFILES if name in payload["profiles"]]
    for name in tracking.select_profiles(None):
        if name in tracking.REAL_PROFILES and name not in real_ran:
            assert f"{name}: SKIPPED" in text
            continue
        role = "TUNING" if payload["profiles"][name]["role"] == "tuning" else "HELD OUT"
        assert f"[{name} [{role}]" in text  # its table
        assert f"[{name}] vs our ByteTrack" in text  # its targets
        for tracker in trackers:
            metrics = payload["accuracy"][name][tracker]
            assert 0.0 <= metrics["HOTA"] <= 1.0 and metrics["IDSW"] >= 0
    if real_ran:
        assert len(list((tmp_path / "cache" / "detector_streams").glob("*/*.txt"))) == len(real_ran)
    assert "worst profile per tracker" in text
    for tracker in trackers:
        worst = payload["worst"][tracker]["all_HOTA"]
        assert worst["value"] == min(payload["accuracy"][p][tracker]["HOTA"] for p in payload["accuracy"])
    if has_boxmot:
        assert any(line.startswith("[worst profile] HOTA: JPTrack") for line in payload["targets"])
        assert "BoT-SORT without ReID" in text
        assert "sequence by sequence: where it is behind" in text
        for name, entry in payload["sequence_margins"].items():
            sequences = payload["accuracy_per_sequence"][name]["JPTrack JCMA+PMR"]
            assert entry["sequences"] == len(sequences) == len(payload["profiles"][name]["sequences"])
    for name in payload["accuracy"]:  # one figure per sequence, per tracker
        for tracker in trackers:
            assert set(payload["accuracy_per_sequence"][name][tracker]) == {
                s["name"] for s in payload["profiles"][name]["sequences"]
            }
    assert "identity switches by event" in text
    for name in payload["id_events"]:
        events = payload["id_events"][name]["JPTrack JCMA+PMR"]
        assert sum(events.values()) == payload["accuracy"][name]["JPTrack JCMA+PMR"]["IDSW"]
        mechanisms = payload["recoveries_by_mechanism"][name]
        assert list(mechanisms) == ["JPTrack JCMA+PMR"]
        assert sum(mechanisms["JPTrack JCMA+PMR"].values()) == events["recovery onto another target"]
    for size in ("3", "50"):
        for tracker in trackers:
            assert payload["speed"][size][tracker]["mean_ms"] > 0


def _switch(frame: int, new_id: int, category: str) -> IdSwitchEvent:
    return IdSwitchEvent(frame, 1, 99, new_id, category, "", frame - 5, 1, "ended at 1")


def test_recoveries_onto_another_target_are_split_by_what_brought_the_track_back() -> None:
    """The latest re-attachment of the new id at or before the switch decides; switches of other
    categories are not counted; a new id never re-attached is unattributed."""
    fps = 10.0
    log = [(0.5, 7, "first stage"), (2.0, 7, "PMR"), (3.0, 7, "relink"), (1.0, 8, "relink")]
    events = [
        _switch(26, 7, RECOVERY_OTHER),  # t = 2.5: PMR at 2.0 is the latest before it
        _switch(21, 7, RECOVERY_OTHER),  # t = 2.0 exactly: PMR
        _switch(11, 8, RECOVERY_OTHER),  # t = 1.0: the relink at 1.0
        _switch(40, 9, RECOVERY_OTHER),  # never re-attached
        _switch(40, 7, SWAP),  # another category
    ]
    counts = tracking.recoveries_by_mechanism(events, log, fps)
    assert counts == {"first stage": 0, "PMR": 2, "relink": 1, tracking.UNATTRIBUTED: 1}
