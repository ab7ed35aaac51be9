"""int8 quantization of a shipped detector (onnxruntime only) keeps its detections close to fp32."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from gldt_core.detect import LocalDetector, shipped_model_path
from gldt_core.eval.detection_metrics import box_iou
from gldt_core.export.quantize import quantize_model
from gldt_core.io.mot import read_mot
from gldt_core.paths import halmstad_root

ROOT = halmstad_root()


@pytest.mark.skipif(not (ROOT / "videos").is_dir(), reason=f"calibration needs the real Halmstad clips in {ROOT}")
def test_int8_local_model_finds_the_same_drone(tmp_path: Path) -> None:
    out = quantize_model(shipped_model_path("local"), tmp_path / "local_int8.onnx", ROOT, count=4)
    assert "int8" in json.loads(out.with_suffix(".json").read_text())["quantized"]
    gt = read_mot(ROOT / "gt" / "V_DRONE_064.txt")
    cap = cv2.VideoCapture(str(ROOT / "videos" / "V_DRONE_064.mp4"))
    for _ in range(60):
        ok, frame = cap.read()
    cap.release()
    x, y, w, h = gt[(gt[:, 0] == 60) & (gt[:, 7] == 1)][0, 2:6]
    roi = np.array([[x + w / 2 - 150, y + h / 2 - 150, x + w / 2 + 150, y + h / 2 + 150]]).round()
    fp32 = LocalDetector(score_threshold=0.25, num_threads=1, second_stage=None).detect_rois(frame, roi)
    int8 = LocalDetector(out, score_threshold=0.25, num_threads=1, second_stage=None).detect_rois(frame, roi)
    assert len(fp32) and len(int8)
    assert box_iou(fp32[:1, :4], int8[:1, :4])[0, 0] > 0.7
    assert int8[0, 5] == fp32[0, 5]


@pytest.mark.skipif(not (ROOT / "videos").is_dir(), reason=f"calibration needs the real Halmstad clips in {ROOT}")
def test_int8_export_over_am_yolo_drops_the_split_pair_it_made_stale(tmp_path: Path, capsys) -> None:
    """The quantized graph cannot be split (its frame batch sits between QDQ nodes), so the old
    pair, made from the fp32 file, is removed instead of left to warn on every start."""
    from gldt_core.cli.export import _refresh_or_drop_split_pair
    from gldt_core.detect import GlobalDetector
    from gldt_core.detect.feature_reuse import features_path, reuse_path

    source = shipped_model_path("global")
    for path in (source, source.with_suffix(".json"), features_path(source), reuse_path(source)):
        shutil.copy(path, tmp_path / path.name)
    model = tmp_path / source.name
    quantize_model(model, model, ROOT, count=2)
    _refresh_or_drop_split_pair(model)
    assert "removed global_amyolo.features.onnx and global_amyolo.reuse.onnx" in capsys.readouterr().out
    assert not features_path(model).exists() and not reuse_path(model).exists()
    assert GlobalDetector(model, second_stage=None, num_threads=1).feature_reuse is None
