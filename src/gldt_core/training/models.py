"""AM-YOLO (dual-frame global detector) and the YOLO11-P2-style local detector.

Both share one YOLO11-shaped body: a backbone of strided Conv + C3k2 stages ending in SPPF and
C2PSA, an FPN/PAN neck that goes all the way up to stride 4 (the P2 level tiny drones need), and an
anchor-free decoupled head with DFL box regression. AM-YOLO runs the previous and current frame
through the *same* backbone weights (one batch of 2B) and fuses them with :class:`~.stff.STFF` after
the stages listed in ``stff_levels``; with ``stff_levels=()`` it is the same network seeing only the
current frame (the ablation baseline). Widths and depths come from :class:`ModelSpec` so the
shipped CPU models can be far smaller than YOLO11n.

In training mode the models return the raw per-level maps for the loss; in eval mode they return
``(B, 4 + nc, A)``: boxes ``x1, y1, x2, y2`` normalised by the input width/height and per-class
sigmoid scores, which is what gets exported to ONNX so the runtime only scales, thresholds, runs
NMS and maps boxes back.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn

from gldt_core.training.blocks import C2PSA, DFL, SPPF, C3k2, Conv
from gldt_core.training.stff import STFF

LEVEL_STRIDES = {2: 4, 3: 8, 4: 16, 5: 32}


@dataclass
class ModelSpec:
    """Architecture hyper-parameters; every field is settable from the YAML training config."""

    channels: tuple[int, int, int, int, int] = (8, 16, 32, 64, 96)  # stem(P1), P2, P3, P4, P5
    depth: int = 1  # repeats inside every C3k2
    num_classes: int = 3
    reg_max: int = 8
    head_levels: tuple[int, ...] = (2, 3, 4, 5)
    dual_frame: bool = True  # global model: takes (previous, current)
    stff_levels: tuple[int, ...] = (2, 3, 4)
    stff_windows: tuple[int, ...] = (8, 8, 4)
    stff_heads: int = 1
    stff_motion_dim: int = 16
    stff_alpha: float = 0.1

    def __post_init__(self) -> None:
        widths = tuple(int(c) for c in self.channels)
        self.head_levels = tuple(sorted(int(level) for level in self.head_levels))
        self.stff_levels = tuple(int(level) for level in self.stff_levels)
        self.stff_windows = tuple(int(w) for w in self.stff_windows)
        if len(widths) != 5:
            raise ValueError(f"channels needs 5 widths (P1..P5), got {widths}")
        self.channels = (widths[0], widths[1], widths[2], widths[3], widths[4])
        if not self.head_levels or not set(self.head_levels) <= set(LEVEL_STRIDES):
            raise ValueError(f"head_levels must be a non-empty subset of 2..5, got {self.head_levels}")
        if len(self.stff_windows) != len(self.stff_levels):
            raise ValueError("stff_windows needs one window size per entry of stff_levels")
        if self.stff_levels and not self.dual_frame:
            raise ValueError("stff_levels needs dual_frame: true (STFF fuses two frames)")
        if not set(self.stff_levels) <= {2, 3, 4, 5}:
            raise ValueError(f"stff_levels must be within 2..5, got {self.stff_levels}")

    @property
    def strides(self) -> tuple[int, ...]:
        return tuple(LEVEL_STRIDES[level] for level in self.head_levels)

    @property
    def input_multiple(self) -> int:
        """Input sides must be multiples of this (stride 32 and every STFF window must tile)."""
        multiple = 32
        for level, window in zip(self.stff_levels, self.stff_windows):
            multiple = math.lcm(multiple, LEVEL_STRIDES[level] * window)
        return multiple

    def to_dict(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelSpec:
        known = set(cls.__dataclass_fields__)
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown model fields {sorted(unknown)}; known: {sorted(known)}")
        return cls(**data)


class Backbone(nn.Module):
    """YOLO11 backbone split into stages so STFF can sit between them."""

    def __init__(self, spec: ModelSpec):
        super().__init__()
        c1, c2, c3, c4, c5 = spec.channels
        n = spec.depth
        self.stem = Conv(3, c1, 3, 2)
        self.stages = nn.ModuleDict(
            {
                "2": nn.Sequential(Conv(c1, c2, 3, 2), C3k2(c2, c2, n, c3k=False, e=0.25)),
                "3": nn.Sequential(Conv(c2, c3, 3, 2), C3k2(c3, c3, n, c3k=False, e=0.25)),
                "4": nn.Sequential(Conv(c3, c4, 3, 2), C3k2(c4, c4, n, c3k=True)),
                "5": nn.Sequential(Conv(c4, c5, 3, 2), C3k2(c5, c5, n, c3k=True), SPPF(c5, c5, 5), C2PSA(c5, c5, n)),
            }
        )


class DetectHead(nn.Module):
    """Anchor-free decoupled head: a DFL box branch and a light depth-wise class branch per level."""

    strides: torch.Tensor  # a buffer (register_buffer), declared for the type checker

    def __init__(self, channels: list[int], strides: tuple[int, ...], num_classes: int, reg_max: int):
        super().__init__()
        self.nc = num_classes
        self.reg_max = reg_max
        self.no = num_classes + 4 * reg_max
        self.register_buffer("strides", torch.tensor(strides, dtype=torch.float32), persistent=False)
        self.box = nn.ModuleList()
        self.cls = nn.ModuleList()
        for ch in channels:
            # Depth-wise separable 3x3 stacks in both branches (YOLO11 uses them for the class
            # branch): at stride 4 a dense 3x3 head would cost more than the whole backbone.
            self.box.append(_separable_branch(ch, max(16, ch), 4 * reg_max))
            self.cls.append(_separable_branch(ch, max(16, ch), num_classes))
        self.dfl = DFL(reg_max)
        self._init_bias(strides)

    def _init_bias(self, strides: tuple[int, ...]) -> None:
        """Start with a low object prior (few objects per 640 image) so early training is stable."""
        for box, cls, stride in zip(self.box, self.cls, strides):
            _prediction_bias(box).data[:] = 1.0
            _prediction_bias(cls).data[:] = math.log(5 / self.nc / (640 / stride) ** 2)

    def forward(self, feats: list[torch.Tensor]) -> list[torch.Tensor] | torch.Tensor:
        maps = [torch.cat((box(x), cls(x)), 1) for x, box, cls in zip(feats, self.box, self.cls)]
        if self.training:
            return maps
        return self.decode(maps)

    def decode(self, maps: list[torch.Tensor]) -> torch.Tensor:
        """Raw maps -> ``(B, 4 + nc, A)`` xyxy boxes (normalised to the input size) and sigmoid class scores."""
        b = maps[0].shape[0]
        flat = torch.cat([m.view(b, self.no, -1) for m in maps], 2)
        box, cls = flat.split((4 * self.reg_max, self.nc), 1)
        anchors, stride = make_anchors(maps, self.strides)
        dist = self.dfl(box)  # (B, 4, A) in stride units
        lt, rb = dist.chunk(2, 1)
        anchors = anchors.transpose(0, 1).unsqueeze(0)  # (1, 2, A)
        xyxy = torch.cat((anchors - lt, anchors + rb), 1) * stride.transpose(0, 1).unsqueeze(0)
        # Normalise by the input size: [0, 1] coordinates keep float32 rounding far below a
        # pixel and make the exported output independent of the (dynamic) input size.
        in_h = maps[0].shape[2] * self.strides[0]
        in_w = maps[0].shape[3] * self.strides[0]
        xyxy = xyxy / torch.stack((in_w, in_h, in_w, in_h)).view(1, 4, 1)
        return torch.cat((xyxy, cls.sigmoid()), 1)


def _separable_branch(ch: int, hidden: int, out: int) -> nn.Sequential:
    """DW3x3 -> PW1x1 -> DW3x3 -> PW1x1 -> 1x1 prediction conv (two 3x3 receptive-field steps)."""
    return nn.Sequential(
        Conv(ch, ch, 3, g=ch),
        Conv(ch, hidden, 1),
        Conv(hidden, hidden, 3, g=hidden),
        Conv(hidden, hidden, 1),
        nn.Conv2d(hidden, out, 1),
    )


def _prediction_bias(branch: nn.Module) -> torch.Tensor:
    """The bias of a branch's final prediction conv (the last layer of :func:`_separable_branch`)."""
    assert isinstance(branch, nn.Sequential)
    conv = branch[-1]
    assert isinstance(conv, nn.Conv2d) and conv.bias is not None
    return conv.bias


def make_anchors(
    maps: list[torch.Tensor], strides: torch.Tensor, offset: float = 0.5
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cell-centre anchor points ``(A, 2)`` in grid units of their level and their strides ``(A, 1)``."""
    points, stride_list = [], []
    for i, m in enumerate(maps):
        h, w = m.shape[2], m.shape[3]
        sx = torch.arange(w, dtype=m.dtype, device=m.device) + offset
        sy = torch.arange(h, dtype=m.dtype, device=m.device) + offset
        yy, xx = torch.meshgrid(sy, sx, indexing="ij")
        points.append(torch.stack((xx, yy), -1).view(-1, 2))
        stride_list.append(torch.ones(h * w, 1, dtype=m.dtype, device=m.device) * strides[i])
    return torch.cat(points), torch.cat(stride_list)


class Detector(nn.Module):
    """AM-YOLO when ``spec.dual_frame`` (forward(previous, current)), else the local P2 detector."""

    def __init__(self, spec: ModelSpec):
        super().__init__()
        self.spec = spec
        c = dict(zip((1, 2, 3, 4, 5), spec.channels))
        n = spec.depth
        self.backbone = Backbone(spec)
        self.stff = nn.ModuleDict(
            {
                str(level): STFF(c[level], window, spec.stff_heads, spec.stff_motion_dim, spec.stff_alpha)
                for level, window in zip(spec.stff_levels, spec.stff_windows)
            }
        )
        # FPN (top-down) then PAN (bottom-up) neck reaching P2.
        self.td4 = C3k2(c[5] + c[4], c[4], n)
        self.td3 = C3k2(c[4] + c[3], c[3], n)
        self.td2 = C3k2(c[3] + c[2], c[2], n)
        self.down2 = Conv(c[2], c[2], 3, 2)
        self.bu3 = C3k2(c[2] + c[3], c[3], n)
        self.down3 = Conv(c[3], c[3], 3, 2)
        self.bu4 = C3k2(c[3] + c[4], c[4], n)
        self.down4 = Conv(c[4], c[4], 3, 2)
        self.bu5 = C3k2(c[4] + c[5], c[5], n, c3k=True)
        self.upsample = nn.Upsample(scale_factor=2, mode="nearest")
        self.head = DetectHead([c[level] for level in spec.head_levels], spec.strides, spec.num_classes, spec.reg_max)

    def _features(self, current: torch.Tensor, previous: torch.Tensor | None) -> dict[int, torch.Tensor]:
        """Backbone levels of the current frame, fused with the previous frame where configured."""
        multiple = self.spec.input_multiple
        h, w = current.shape[-2:]
        if h % multiple or w % multiple:
            raise ValueError(f"input {w}x{h} must have sides divisible by {multiple}")
        last_fused = max(self.spec.stff_levels, default=0)
        two = previous is not None and last_fused > 0
        x = torch.cat((current, previous), 0) if two and previous is not None else current
        b = current.shape[0]
        x = self.backbone.stem(x)
        levels: dict[int, torch.Tensor] = {}
        for level in (2, 3, 4, 5):
            if two and level > last_fused:  # the previous frame is no longer needed
                x = x[:b]
                two = False
            x = self.backbone.stages[str(level)](x)
            if two and str(level) in self.stff:
                fused = self.stff[str(level)](x[:b], x[b:])
                x = torch.cat((fused, x[b:]), 0)
            levels[level] = x[:b] if two else x
        return levels

    def forward(self, *frames: torch.Tensor) -> list[torch.Tensor] | torch.Tensor:
        """``forward(previous, current)`` for dual-frame models, ``forward(image)`` otherwise."""
        if self.spec.dual_frame:
            if len(frames) != 2:
                raise ValueError(f"dual-frame model needs (previous, current), got {len(frames)} tensors")
            previous, current = frames
            if previous.shape != current.shape:
                raise ValueError(f"frame shapes differ: {tuple(previous.shape)} vs {tuple(current.shape)}")
        else:
            if len(frames) != 1:
                raise ValueError(f"single-frame model needs one image tensor, got {len(frames)}")
            previous, current = None, frames[0]
        p = self._features(current, previous)
        top = max(self.spec.head_levels)
        h4 = self.td4(torch.cat((self.upsample(p[5]), p[4]), 1))
        h3 = self.td3(torch.cat((self.upsample(h4), p[3]), 1))
        o2 = self.td2(torch.cat((self.upsample(h3), p[2]), 1))
        outs = {2: o2}
        if top >= 3:
            outs[3] = self.bu3(torch.cat((self.down2(o2), h3), 1))
        if top >= 4:
            outs[4] = self.bu4(torch.cat((self.down3(outs[3]), h4), 1))
        if top >= 5:
            outs[5] = self.bu5(torch.cat((self.down4(outs[4]), p[5]), 1))
        return self.head([outs[level] for level in self.spec.head_levels])

    def stff_alphas(self) -> list[float]:
        """The learned residual weight alpha (eq. 5) of each STFF, in ``spec.stff_levels`` order."""
        alphas = []
        for fusion in self.stff.values():
            assert isinstance(fusion, STFF)
            alphas.append(float(fusion.alpha))
        return alphas


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
