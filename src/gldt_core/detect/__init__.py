"""Runtime detectors (onnxruntime only, never torch): the global AM-YOLO and the local ROI detector.

    from gldt_core.detect import GlobalDetector, LocalDetector, DetectorConfigError
    gd = GlobalDetector()                       # shipped model, CPU
    dets = gd.detect(previous_bgr, current_bgr)  # (N, 6) [x1, y1, x2, y2, score, class_id]
    ld = LocalDetector()
    dets = ld.detect_rois(frame_bgr, rois)       # (N, 7) [..., roi_index], one batch for all ROIs

Boxes are full-frame pixels; class_id is the MOTChallenge class code (1 drone, 2 bird, 3 airplane).
Each detector's work is split in two public halves where the ROS graph splits it over processes:
``GlobalDetector.prepare`` / ``GlobalDetector.detect_prepared`` and ``LocalDetector.crop`` /
``LocalDetector.detect_crops``; ``detect``, ``detect_pair`` and ``detect_rois`` call the same
halves, so the graph and the offline GL-DT system give identical boxes.

Modules: :mod:`.session` (opening and checking a model), :mod:`.global_detector`,
:mod:`.local_detector`, :mod:`.feature_reuse` (AM-YOLO's split pair), :mod:`.postprocess`
(letterbox, decoding, NMS), :mod:`.fusion` (two detectors' calibrated boxes as one set),
:mod:`.shipped` (the shipped models), :mod:`.video` (a detector over a video file). Nothing here
imports the export-time code of :mod:`gldt_core.export`.
"""

from gldt_core.detect.global_detector import GlobalCarry, GlobalDetector
from gldt_core.detect.local_detector import LocalDetector
from gldt_core.detect.session import DetectorConfigError
from gldt_core.detect.shipped import DRONE_CLASS_ID, MODELS_DIR, shipped_model_path

__all__ = [
    "DRONE_CLASS_ID",
    "MODELS_DIR",
    "DetectorConfigError",
    "GlobalCarry",
    "GlobalDetector",
    "LocalDetector",
    "shipped_model_path",
]
