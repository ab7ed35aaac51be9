"""`gldt bench seeds`: variants compared over their seeds' detection reports."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gldt_core.bench.seeds import (
    clip_false_drones,
    clip_false_track_rows,
    end_to_end_figures,
    format_summary,
    parse_variant,
    seed_figures,
    summarise,
)
from gldt_core.cli import main


def report(
    ap_val: float,
    ap_val_b: float,
    fd_val: float,
    fd_val_b: float,
    accuracy: float | None = None,
    by_clip: dict[str, int] | None = None,
) -> dict:
    def row(ap: float) -> dict:
        return {"fused+2nd": {"ap50": ap, "precision_at_threshold": 0.9, "recall_at_threshold": ap - 0.1}}

    out: dict = {
        "datasets": {"real-val": row(ap_val), "real-val-b": row(ap_val_b), "synthetic-test": row(0.1)},
        "false_drones_per_frame": {"real-val": {"fused+2nd": fd_val}, "real-val-b": {"fused+2nd": fd_val_b}},
    }
    if accuracy is not None:
        out["second_stage"] = {"path": "x.onnx", "calibration_clip_figures": {"accuracy": accuracy}}
    if by_clip is not None:  # false drones of the fused row on the real-val bird/airplane clips
        out["false_drones_by_clip"] = {"real-val": {"fused+2nd": by_clip, "local": {"V_BIRD_004": 9}}}
    return out


def write_reports(folder: Path, reports: dict[str, dict]) -> None:
    """Each report as ``folder/<name>/report.json``, where ``gldt bench detection --out`` puts it."""
    for name, content in reports.items():
        (folder / name).mkdir()
        (folder / name / "report.json").write_text(json.dumps(content))


def test_a_seed_is_read_by_its_worst_split() -> None:
    figures = seed_figures(report(0.87, 0.93, 0.10, 0.12, 0.88), "fused+2nd")
    assert figures["worst split AP50"] == 0.87  # the synthetic row is not a validation split
    assert figures["worst split false drones/frame"] == 0.12
    assert figures["calibration accuracy"] == 0.88
    assert figures["recall real-val-b"] == pytest.approx(0.83)
    assert "calibration accuracy" not in seed_figures(report(0.87, 0.93, 0.1, 0.1), "fused+2nd")
    with pytest.raises(ValueError, match="^r.json: no row 'local' for real-val"):
        seed_figures(report(0.87, 0.93, 0.1, 0.1), "local", "r.json")
    with pytest.raises(ValueError, match="no real validation split"):
        seed_figures({"datasets": {}}, "fused+2nd")


def test_variants_are_summarised_over_their_seeds_against_the_first() -> None:
    peer = summarise(
        [
            seed_figures(report(0.86, 0.93, 0.10, 0.06), "fused+2nd"),
            seed_figures(report(0.87, 0.94, 0.13, 0.11), "fused+2nd"),
        ]
    )
    other = summarise([seed_figures(report(0.85, 0.93, 0.04, 0.03, 0.9), "fused+2nd")])
    assert peer["worst split AP50"] == {"mean": pytest.approx(0.865), "min": 0.86, "max": 0.87, "seeds": 2}
    assert peer["worst split false drones/frame"]["mean"] == pytest.approx(0.115)
    table = format_summary({"shipped": peer, "grey": other})
    line = next(row for row in table.splitlines() if row.startswith("worst split false drones/frame"))
    assert "0.1150 [0.100-0.130] n2" in line and "-0.0750" in line and line.endswith("0.0300")
    accuracy = next(row for row in table.splitlines() if row.startswith("calibration accuracy"))
    assert "0.9000 [0.900-0.900] n1" in accuracy  # the peer has none: no difference, no spread
    assert accuracy.split()[-2:] == ["-", "-"]
    alone = format_summary({"grey": other, "shipped": peer})  # a peer of one seed has no spread
    assert next(row for row in alone.splitlines() if row.startswith("worst split AP50")).endswith(" -")


def test_reports_that_lack_a_figure_or_differ_in_their_runs_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    partial = report(0.87, 0.93, 0.1, 0.1)
    del partial["false_drones_per_frame"]["real-val-b"]
    with pytest.raises(ValueError, match="^p.json: false drones of real-val-b missing or not a table$"):
        seed_figures(partial, "fused+2nd", "p.json")
    broken = report(0.87, 0.93, 0.1, 0.1)
    del broken["datasets"]["real-val"]["fused+2nd"]["ap50"]
    with pytest.raises(ValueError, match="^b.json: real-val fused\\+2nd has no number 'ap50'$"):
        seed_figures(broken, "fused+2nd", "b.json")
    with pytest.raises(ValueError, match="the report missing or not a table"):
        seed_figures([1, 2], "fused+2nd")
    with pytest.raises(ValueError, match="without empty reports"):
        parse_variant("grey=a,")
    one, other = report(0.87, 0.93, 0.1, 0.1), report(0.87, 0.93, 0.1, 0.1)
    one["real-val_clips"], other["real-val_clips"] = ["V_DRONE_004"], ["V_DRONE_011"]
    (tmp_path / "one.json").write_text(json.dumps(one))
    (tmp_path / "other.json").write_text(json.dumps(other))
    assert (
        main(["bench", "seeds", "--variant", f"a={tmp_path / 'one.json'}", "--variant", f"b={tmp_path / 'other.json'}"])
        == 2
    )
    assert "other.json: benched on other clips or at other settings than" in capsys.readouterr().err


def test_the_command_reads_reports_or_their_folders_and_says_what_is_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    write_reports(
        tmp_path,
        {
            "a0": report(0.86, 0.93, 0.1, 0.06),
            "a1": report(0.87, 0.94, 0.13, 0.11),
            "b0": report(0.85, 0.93, 0.04, 0.03),
        },
    )
    out = tmp_path / "summary.json"
    code = main(
        [
            "bench", "seeds", "--variant", f"shipped={tmp_path / 'a0'},{tmp_path / 'a1' / 'report.json'}",
            "--variant", f"grey={tmp_path / 'b0'}", "--json", str(out),
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    assert "row fused+2nd" in printed and "grey - shipped" in printed
    assert json.loads(out.read_text())["variants"]["shipped"]["worst split AP50"]["seeds"] == 2
    assert parse_variant("x=a, b")[0] == "x"
    with pytest.raises(ValueError, match="expected NAME=REPORT"):
        parse_variant("shipped")
    (tmp_path / "bad.json").write_text("{")
    assert main(["bench", "seeds", "--variant", f"x={tmp_path / 'bad.json'}"]) != 0
    assert "bad.json: not a JSON report" in capsys.readouterr().err
    assert main(["bench", "seeds", "--variant", f"x={tmp_path / 'none.json'}"]) != 0
    assert "none.json: no such report" in capsys.readouterr().err


def test_the_false_drones_are_shown_clip_by_clip_where_any_seed_had_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    seeds = {
        "a0": {"V_AIRPLANE_049": 14, "V_AIRPLANE_019": 12, "V_BIRD_004": 0},
        "a1": {"V_AIRPLANE_049": 15, "V_AIRPLANE_019": 10, "V_BIRD_004": 0},
        "b0": {"V_AIRPLANE_049": 13, "V_AIRPLANE_019": 2, "V_BIRD_004": 0},
    }
    write_reports(tmp_path, {name: report(0.87, 0.93, 0.1, 0.1, by_clip=by_clip) for name, by_clip in seeds.items()})
    assert clip_false_drones(report(0.87, 0.93, 0.1, 0.1, by_clip=seeds["a0"]), "local") == {"real-val V_BIRD_004": 9}
    assert clip_false_drones(report(0.87, 0.93, 0.1, 0.1), "fused+2nd") == {}  # a report from before the list
    out = tmp_path / "summary.json"
    code = main(
        [
            "bench", "seeds", "--variant", f"shipped={tmp_path / 'a0'},{tmp_path / 'a1'}",
            "--variant", f"border={tmp_path / 'b0'}", "--json", str(out),
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out.split("false drones by bird/airplane clip")[1].splitlines()
    line = next(row for row in printed if row.startswith("real-val V_AIRPLANE_019"))
    assert "11.0 [10-12] n2" in line and "2.0 [2-2] n1" in line and "-9.0" in line and line.endswith("2.0")
    assert not any("V_BIRD_004" in row for row in printed)  # no seed called a drone there
    summary = json.loads(out.read_text())["false_drones_by_clip"]
    assert summary["border"]["real-val V_AIRPLANE_049"]["mean"] == 13.0


def ablation_report(split: str, idf1: float, false_rows: float, rows_by_clip: dict[str, int], clips: int = 2) -> dict:
    """What ``gldt bench ablation --variants GD+LD+JPTrack --other-clips N --json`` writes for one split."""
    row = {"variant": "GD+LD+JPTrack", "IDF1": idf1, "MOTA": idf1 - 10.0, "HOTA": idf1 - 20.0, "IDSW": 3}
    return {
        "oracle": False,
        "variants": ["GD+LD+JPTrack"],
        f"halmstad_{split}": [row],
        f"clips_{split}": [f"V_DRONE_{k:03d}" for k in range(clips)],
        f"false_drone_track_rows_per_frame_{split}": false_rows,
        f"false_drone_track_rows_by_clip_{split}": rows_by_clip,
        f"false_drone_tracks_{split}": [],
        f"other_clips_{split}": ["V_AIRPLANE_022", "V_AIRPLANE_049", "V_BIRD_004"],
    }


def test_end_to_end_reports_give_the_shipped_systems_figures_per_split() -> None:
    figures = end_to_end_figures(ablation_report("val_b", 92.0, 0.1, {"V_AIRPLANE_022": 287}))
    assert figures == {
        "MOTA val_b": 82.0,
        "IDF1 val_b": 92.0,
        "HOTA val_b": 72.0,
        "IDSW val_b": 3.0,
        "false drone track rows/frame val_b": 0.1,
    }
    assert clip_false_track_rows(ablation_report("val", 84.0, 0.1, {"V_AIRPLANE_049": 309})) == {
        "val V_AIRPLANE_049": 309.0
    }
    without = ablation_report("val", 84.0, 0.1, {})
    without["halmstad_val"][0]["variant"] = "GD+JPTrack"
    with pytest.raises(ValueError, match="^e.json: no GD\\+LD\\+JPTrack row for val"):
        end_to_end_figures(without, "e.json")


def test_the_command_reads_end_to_end_reports_beside_detection_reports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A variant lists its seeds' ablation reports of both splits (and a detection report): each
    figure is summarised over the reports that give it, and reports are checked against the first
    of their own kind and split, so a val and a val_b report do not clash."""
    reports = {
        "a0_val": ablation_report("val", 84.0, 0.14, {"V_AIRPLANE_049": 309, "V_BIRD_004": 0}),
        "a2_val": ablation_report("val", 85.0, 0.10, {"V_AIRPLANE_049": 200}),
        "a0_val_b": ablation_report("val_b", 92.0, 0.11, {"V_AIRPLANE_022": 287}),
        "b0_val": ablation_report("val", 84.5, 0.06, {"V_AIRPLANE_049": 20, "V_BIRD_004": 56}),
        "b0_val_b": ablation_report("val_b", 91.0, 0.07, {"V_AIRPLANE_022": 10}),
    }
    for name, content in reports.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(content))
    write_reports(tmp_path, {"det": report(0.87, 0.93, 0.1, 0.1)})
    path = {name: str(tmp_path / f"{name}.json") for name in reports}
    shipped = f"{path['a0_val']},{path['a2_val']},{path['a0_val_b']},{tmp_path / 'det'}"
    out = tmp_path / "summary.json"
    code = main(
        [
            "bench", "seeds", "--variant", f"shipped={shipped}",
            "--variant", f"bgrey={path['b0_val']},{path['b0_val_b']}", "--json", str(out),
        ]
    )  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out
    idf1 = next(row for row in printed.splitlines() if row.startswith("IDF1 val "))
    assert "84.5000 [84.000-85.000] n2" in idf1 and "+0.0000" in idf1 and idf1.endswith("1.0000")
    assert next(row for row in printed.splitlines() if row.startswith("worst split AP50")).split()[-3:-1] == ["-", "-"]
    rows = printed.split("false drone track rows by bird/airplane clip")[1].splitlines()
    bird = next(row for row in rows if row.startswith("val V_BIRD_004"))
    assert "0.0 [0-0] n1" in bird and "56.0 [56-56] n1" in bird  # shown: one seed of one variant had rows there
    summary = json.loads(out.read_text())
    assert summary["variants"]["shipped"]["IDF1 val_b"]["seeds"] == 1
    assert summary["false_drone_track_rows_by_clip"]["shipped"]["val V_AIRPLANE_049"]["mean"] == 254.5
    other_clips = ablation_report("val", 84.0, 0.1, {"V_AIRPLANE_049": 1}, clips=3)
    (tmp_path / "three.json").write_text(json.dumps(other_clips))
    assert main(["bench", "seeds", "--variant", f"x={path['a0_val']},{tmp_path / 'three.json'}"]) != 0
    assert "three.json: benched on other clips or at other settings than" in capsys.readouterr().err
