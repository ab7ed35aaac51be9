"""The one parameter schema of the graph: declared with descriptors, documented from here.

Each node declares exactly the entries listed for it, with a ``ParameterDescriptor`` carrying
the description and the allowed range, so ``ros2 param describe`` and the README table (made by
:func:`markdown_table`, checked by a test) can never disagree with the code.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gldt_core.schedule.roi import DEFAULT_ROI_SIZE
from gldt_core.schedule.scheduler import DEFAULT_N_GLOBAL, DEFAULT_N_LOCAL, DEFAULT_N_MISS
from gldt_core.system.config import DetectorSettings


@dataclass(frozen=True)
class ParamSpec:
    """One ROS parameter: name, default, description and (for numbers) an inclusive range."""

    name: str
    default: Any
    description: str
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] = ()

    def validate(self, value: Any) -> None:
        """Raise ``ValueError`` naming the parameter when ``value`` is out of range/choices."""
        if self.choices and value not in self.choices:
            raise ValueError(f"parameter {self.name}={value!r} must be one of {list(self.choices)}")
        if self.minimum is not None and value < self.minimum:
            raise ValueError(f"parameter {self.name}={value!r} is below its minimum {self.minimum}")
        if self.maximum is not None and value > self.maximum:
            raise ValueError(f"parameter {self.name}={value!r} is above its maximum {self.maximum}")


_CAMERA_QOS = ParamSpec(
    "camera_qos", "sensor_data", "QoS of camera input: match the publisher", choices=("sensor_data", "reliable")
)
_DETECTOR_DEFAULTS = DetectorSettings()
_CLASSES_DEFAULT = ",".join(str(c) for c in _DETECTOR_DEFAULTS.classes) if _DETECTOR_DEFAULTS.classes else ""
_SCORE_THRESHOLD = ParamSpec(
    "score_threshold",
    _DETECTOR_DEFAULTS.score_threshold,
    "Lowest detection score kept (default: the offline pipeline's); -1 = the detector's own default (0.25)",
    -1.0,
    1.0,
)
_DIAG_PERIOD = ParamSpec("diagnostics_period", 1.0, "Seconds between /diagnostics messages", 0.1, 60.0)

SCHEMA: dict[str, tuple[ParamSpec, ...]] = {
    "frame_pair_buffer": (
        ParamSpec(
            "image_transport",
            "auto",
            "Camera input: Image on image_raw, CompressedImage on image_raw/compressed, or both (auto)",
            choices=("auto", "raw", "compressed"),
        ),
        _CAMERA_QOS,
        ParamSpec(
            "global_model_path",
            "",
            "AM-YOLO ONNX file whose input size the pair is letterboxed to; empty = shipped model",
        ),
        _DIAG_PERIOD,
    ),
    "global_detector": (
        ParamSpec("model_path", "", "AM-YOLO ONNX file; empty = the model shipped with gldt_core"),
        _SCORE_THRESHOLD,
        ParamSpec(
            "classes",
            _CLASSES_DEFAULT,
            "Comma-separated class ids to detect and pass to the tracker (1 drone, 2 bird, 3 airplane); the model is asked about these only; empty = all",
        ),
        ParamSpec(
            "providers",
            "CPUExecutionProvider",
            "Comma-separated onnxruntime execution providers (CUDA, TensorRT on Jetson)",
        ),
        ParamSpec("num_threads", 0, "onnxruntime intra-op threads; 0 = onnxruntime default", 0, 64),
        ParamSpec(
            "pair_queue_depth",
            1,
            "Frame pairs kept while the detector runs; 1 = only the newest, so a slow detector skips pairs instead of falling behind",
            1,
            100,
        ),
        _DIAG_PERIOD,
    ),
    "local_detector": (
        ParamSpec("model_path", "", "Local P2 ONNX file; empty = the model shipped with gldt_core"),
        _SCORE_THRESHOLD,
        ParamSpec(
            "classes",
            _CLASSES_DEFAULT,
            "Comma-separated class ids to detect and pass to the tracker; the model is asked about these only; empty = all",
        ),
        ParamSpec(
            "nms_iou",
            _DETECTOR_DEFAULTS.nms_iou,
            "IoU above which detections of overlapping ROIs are merged",
            0.01,
            1.0,
        ),
        ParamSpec("providers", "CPUExecutionProvider", "Comma-separated onnxruntime execution providers"),
        ParamSpec("num_threads", 0, "onnxruntime intra-op threads; 0 = onnxruntime default", 0, 64),
        _DIAG_PERIOD,
    ),
    "mode_scheduler": (
        ParamSpec(
            "global_frames", DEFAULT_N_GLOBAL, "N_g: frames of global detection before trying local mode", 1, 10000
        ),
        ParamSpec("local_frames", DEFAULT_N_LOCAL, "N_l: most frames in local mode before a global refresh", 1, 10000),
        ParamSpec(
            "miss_frames",
            DEFAULT_N_MISS,
            "N_m: local frames without any detection before returning to global",
            1,
            10000,
        ),
        ParamSpec("roi_size", DEFAULT_ROI_SIZE, "Side of a local-detection ROI [px]", 32, 2048),
        ParamSpec(
            "report_timeout",
            5.0,
            "Lockstep: seconds to wait for a LOCAL frame's detections before planning on (pipeline --lockstep sets its --frame-timeout)",
            0.1,
            600.0,
        ),
        ParamSpec(
            "lockstep",
            False,
            "Plan a frame only after the previous LOCAL frame's detections arrived (deterministic replay)",
        ),
        _DIAG_PERIOD,
    ),
    "jptrack_tracker": (
        ParamSpec(
            "lost_frames_kept",
            DEFAULT_N_MISS,
            "Frames a lost track keeps getting an ROI (offline: track_lost_frames, default N_m)",
            0,
            10000,
        ),
        ParamSpec(
            "tracker",
            "jptrack",
            "Association: JPTrack (JCMA + PMR) or the ByteTrack baseline",
            choices=("jptrack", "bytetrack"),
        ),
        _CAMERA_QOS,
        ParamSpec("publish_markers", True, "Publish visualization_msgs/MarkerArray while someone subscribes"),
        _DIAG_PERIOD,
    ),
}


def parse_classes(text: str) -> tuple[int, ...] | None:
    """``"1,2"`` -> ``(1, 2)``; empty -> ``None`` (all classes). ``ValueError`` names bad items."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    try:
        return tuple(int(item) for item in items) if items else None
    except ValueError:
        raise ValueError(f"parameter classes={text!r} must be comma-separated integers") from None


def detector_kwargs(node_param: Any) -> dict[str, Any]:
    """Constructor arguments of a detector from its node's parameters."""
    kwargs: dict[str, Any] = {
        "model_path": node_param("model_path") or None,
        "providers": tuple(p.strip() for p in node_param("providers").split(",") if p.strip()),
        "num_threads": int(node_param("num_threads")) or None,
        # Ask the model about the tracked classes only, as gldt_core.system.build_detectors does.
        "classes": parse_classes(node_param("classes")),
    }
    if float(node_param("score_threshold")) >= 0:
        kwargs["score_threshold"] = float(node_param("score_threshold"))
    return kwargs


def markdown_table() -> str:
    """The README's parameter table, generated from :data:`SCHEMA`."""
    lines = ["| node | parameter | default | range / choices | description |", "|---|---|---|---|---|"]
    for node, specs in SCHEMA.items():
        for spec in specs:
            if spec.choices:
                allowed = ", ".join(spec.choices)
            elif spec.minimum is not None or spec.maximum is not None:
                allowed = f"[{spec.minimum}, {spec.maximum}]"
            else:
                allowed = ""
            lines.append(f"| {node} | `{spec.name}` | `{spec.default!r}` | {allowed} | {spec.description} |")
    return "\n".join(lines)


def default_yaml() -> str:
    """A ROS parameter file holding every schema default (``/**/node`` matches any namespace)."""
    lines = ["# GL-DT node parameters (defaults). Generated from gldt_ros/interface/params.py; see the README table."]
    for node, specs in SCHEMA.items():
        lines += [f"/**/{node}:", "  ros__parameters:"]
        for spec in specs:
            value = spec.default
            text = (
                ("true" if value else "false")
                if isinstance(value, bool)
                else (f'"{value}"' if isinstance(value, str) else repr(value))
            )
            lines.append(f"    {spec.name}: {text}  # {spec.description}")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    import sys

    if sys.argv[1:] == ["--yaml"]:
        print(default_yaml(), end="")
    elif sys.argv[1:] == ["--markdown"]:
        print(markdown_table())
    else:
        print("usage: python -m gldt_ros.interface.params --yaml | --markdown", file=sys.stderr)
        sys.exit(2)
