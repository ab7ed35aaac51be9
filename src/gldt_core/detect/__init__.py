"""Runtime detectors (onnxruntime only, never torch): the global AM-YOLO and the local ROI detector.

    from gldt_core.detect import GlobalDetector, LocalDetector, DetectorConfigError
    gd = GlobalDetector()                       # shipped model, CPU
    dets = gd.detect(previous_bgr, current_bgr)  # (N, 6) [x1, y1, x2, y2, score, class_id]
    ld = LocalDetector()
    dets = ld.detect_rois(frame_bgr, rois)       # (N, 7) [..., roi_index], one batch for all ROIs

Boxes are full-frame pixels; class_id is the MOTChallenge class code (1 drone, 2 bird, 3 airplane).
"""

from gldt_core.detect.runtime import (
    DRONE_CLASS_ID,
    DetectorConfigError,
    GlobalDetector,
    LocalDetector,
    shipped_model_path,
)

__all__ = ["DRONE_CLASS_ID", "DetectorConfigError", "GlobalDetector", "LocalDetector", "shipped_model_path"]
