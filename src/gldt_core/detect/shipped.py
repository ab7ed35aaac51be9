"""The models shipped in ``gldt_core/models`` and the MOTChallenge class code of drones."""

from __future__ import annotations

from pathlib import Path

MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
DEFAULT_GLOBAL_MODEL = MODELS_DIR / "global_amyolo.onnx"
DEFAULT_LOCAL_MODEL = MODELS_DIR / "local_p2.onnx"
DRONE_CLASS_ID = 1  # MOTChallenge class code of drones

_SHIPPED = {
    "global": DEFAULT_GLOBAL_MODEL,
    "local": DEFAULT_LOCAL_MODEL,
    "global_nostff": MODELS_DIR / "global_nostff.onnx",
    # Opt-in pair trained with half of the draws synthetic (configs/run/balanced_models.yaml),
    # and the balanced AM-YOLO's twin without STFF (the STFF ablation on that data mix).
    "global_balanced": MODELS_DIR / "global_amyolo_balanced.onnx",
    "local_balanced": MODELS_DIR / "local_p2_balanced.onnx",
    "global_nostff_balanced": MODELS_DIR / "global_nostff_balanced.onnx",
}


def shipped_model_path(kind: str) -> Path:
    """Path of a shipped model: ``global``, ``global_nostff``, ``local``, ``global_balanced``, ``local_balanced``
    or ``global_nostff_balanced``."""
    if kind not in _SHIPPED:
        raise ValueError(f"unknown shipped model {kind!r}; choose one of {sorted(_SHIPPED)}")
    return _SHIPPED[kind]
