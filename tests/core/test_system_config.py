"""YAML configuration: defaults from Table I, partial overrides, one-line errors for bad files."""

from __future__ import annotations

from pathlib import Path

import pytest

from gldt_core.system.config import SystemConfig, config_from_dict, load_config
from support import CONFIGS


def test_defaults_are_table_one():
    cfg = SystemConfig()
    assert (cfg.scheduler.n_global, cfg.scheduler.n_local) == (30, 120)
    roi = cfg.scheduler.roi
    assert (roi.roi_size, roi.tau_overlap, roi.tau_distance, roi.tau_safe) == (300, 0.2, 700.0, 0.8)
    assert cfg.tracker.name == "jptrack" and cfg.scheduler.local_enabled
    assert cfg.detector.classes == (1,)  # drones only


def test_null_classes_means_every_class(tmp_path):
    path = tmp_path / "all.yaml"
    path.write_text("detector: {classes: null}\n")
    assert load_config(path).detector.classes is None


def test_partial_yaml_overrides_only_what_it_names(tmp_path):
    path = tmp_path / "cfg.yaml"
    path.write_text(
        "scheduler: {n_local: 60}\nroi: {size: 256, tau_distance: 500}\n"
        "detector: {classes: [0], score_threshold: 0.3}\ntracker: {name: bytetrack}\n"
    )
    cfg = load_config(path)
    assert cfg.scheduler.n_local == 60 and cfg.scheduler.n_global == 30
    assert cfg.scheduler.roi.roi_size == 256 and cfg.scheduler.roi.tau_distance == 500.0
    assert cfg.scheduler.roi.tau_overlap == 0.2
    assert cfg.detector.classes == (0,) and cfg.detector.score_threshold == 0.3
    assert cfg.tracker.name == "bytetrack"


def test_empty_file_is_all_defaults(tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text("")
    assert load_config(path) == SystemConfig()


@pytest.mark.parametrize(
    "text, message",
    [
        ("scheduler: {n_globl: 3}", "scheduler.n_globl: unknown key"),
        ("roi: {tau_overlap: 'high'}", "roi.tau_overlap: expected float"),
        ("scheduler: {n_miss: 0}", "n_miss must be an integer >= 1"),
        ("tracker: {name: sort}", "tracker.name must be one of"),
        ("detectors: {}", "detectors: unknown key"),
        ("roi: {tau_safe: 1.5}", "tau_safe must be in"),
        ("- just a list", "top level must be a mapping"),
        ("scheduler: [1, 2", "not valid YAML"),
        ("tracker: {jptrack: {pmr_size_ratio: 0.5}}", "tracker.jptrack: pmr_size_ratio must be >= 1"),
    ],
)
def test_bad_config_fails_with_one_line_naming_file_and_key(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        load_config(path)
    text_of_error = str(info.value)
    assert message in text_of_error
    assert str(path) in text_of_error
    assert "\n" not in text_of_error


def test_missing_config_file():
    with pytest.raises(FileNotFoundError, match="config file not found"):
        load_config("/nonexistent/gldt.yaml")


def test_ablation_switches():
    cfg = config_from_dict({"scheduler": {"n_global": 10}})
    gd_only = cfg.with_changes(local_enabled=False, tracker="bytetrack")
    assert not gd_only.scheduler.local_enabled and gd_only.scheduler.n_global == 10
    assert gd_only.tracker.name == "bytetrack"


def test_per_tracker_parameters_survive_the_ablation_switch(tmp_path):
    path = tmp_path / "trackers.yaml"
    path.write_text(
        "tracker:\n  name: jptrack\n  jptrack: {t_h: 0.3, new_track_thresh: 0.35}\n"
        "  bytetrack: {track_thresh: 0.3}\n  params: {t_h: 0.4}\n"
    )
    cfg = load_config(path)
    assert cfg.tracker.parameters() == {"t_h": 0.4, "new_track_thresh": 0.35}
    byte = cfg.with_changes(tracker="bytetrack")
    assert byte.tracker.parameters() == {"track_thresh": 0.3}
    assert byte.with_changes(tracker="jptrack").tracker.parameters() == {"t_h": 0.3, "new_track_thresh": 0.35}


def test_per_tracker_parameters_reach_the_built_tracker(tmp_path):
    from gldt_core.system.gldt_system import build_tracker

    cfg = config_from_dict({"tracker": {"jptrack": {"new_track_thresh": 0.35}, "bytetrack": {"track_thresh": 0.3}}})
    assert build_tracker(cfg).config.new_track_thresh == 0.35
    assert build_tracker(cfg.with_changes(tracker="bytetrack"), (640, 512)).config.track_thresh == 0.3


def test_a_relative_model_path_is_found_beside_the_yaml_from_any_working_directory(tmp_path, monkeypatch):
    folder = tmp_path / "configs"
    (tmp_path / "models").mkdir()
    folder.mkdir()
    (tmp_path / "models" / "mine.onnx").write_bytes(b"x")
    cfg = folder / "c.yaml"
    cfg.write_text("detector: {global_model: ../models/mine.onnx, local_model: elsewhere.onnx}\n")
    monkeypatch.chdir(tmp_path / "models")
    config = load_config(cfg)
    assert config.detector.global_model == str((tmp_path / "models" / "mine.onnx").resolve())
    # No such file beside the YAML: the path keeps meaning one from the working directory.
    assert config.detector.local_model == "elsewhere.onnx"


def test_the_shipped_balanced_models_config_points_at_the_shipped_files(tmp_path, monkeypatch):

    monkeypatch.chdir(tmp_path)
    config = load_config(CONFIGS / "run" / "balanced_models.yaml")
    for path in (config.detector.global_model, config.detector.local_model):
        assert Path(path).is_file(), path
    assert config.scheduler == SystemConfig().scheduler, "only the models change"


@pytest.mark.parametrize("name", sorted(path.name for path in (CONFIGS / "run").glob("*.yaml")))
def test_every_shipped_run_config_loads(name):
    """A default that some configs must turn off (tile fusion, which needs the second stage) must
    not leave a shipped config that the loader refuses."""
    config = load_config(CONFIGS / "run" / name)
    # Fusion stays on unless the config is the A/B without it or has no second stage to fuse with.
    fused = name != "no_tile_fusion.yaml" and config.detector.second_stage is not None
    assert config.detector.tile_fusion == fused


def test_the_detectors_are_asked_about_the_tracked_classes(tmp_path):
    from gldt_core.system.gldt_system import build_detectors

    global_detector, local_detector = build_detectors(SystemConfig())
    for detector in (global_detector, local_detector):
        assert detector.classes == (1,) and detector.class_channels.tolist() == [0]
    path = tmp_path / "all.yaml"
    path.write_text("detector: {classes: null}\nscheduler: {local_enabled: false}\n")
    global_detector, local_detector = build_detectors(load_config(path))
    assert global_detector.classes is None and global_detector.class_channels is None and local_detector is None
