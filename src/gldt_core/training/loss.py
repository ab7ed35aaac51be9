"""Detection loss for tiny objects: task-aligned assignment + BCE + CIoU + DFL.

Task-aligned assignment (TAL) picks, for each ground-truth box, the ``top_k`` anchors whose
``score^alpha * IoU^beta`` is highest among anchors whose centre lies in the box. A 12-pixel drone
covers only a handful of stride-4 cells, and after augmentation a box can fall between centres, so
every ground truth is also always offered the anchor nearest its centre: no target is ever left
without a positive, which is the main way small objects get lost in training.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from gldt_core.training.models import make_anchors


def box_iou_pairs(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """IoU of aligned xyxy boxes ``a[..., 4]`` and ``b[..., 4]`` (broadcasting)."""
    inter = (torch.min(a[..., 2], b[..., 2]) - torch.max(a[..., 0], b[..., 0])).clamp(0) * (
        torch.min(a[..., 3], b[..., 3]) - torch.max(a[..., 1], b[..., 1])
    ).clamp(0)
    area_a = (a[..., 2] - a[..., 0]).clamp(0) * (a[..., 3] - a[..., 1]).clamp(0)
    area_b = (b[..., 2] - b[..., 0]).clamp(0) * (b[..., 3] - b[..., 1]).clamp(0)
    return inter / (area_a + area_b - inter + eps)


def ciou(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-7) -> torch.Tensor:
    """Complete IoU of aligned xyxy boxes: IoU minus centre-distance and aspect-ratio penalties."""
    iou = box_iou_pairs(a, b, eps)
    w1, h1 = a[..., 2] - a[..., 0], (a[..., 3] - a[..., 1]).clamp(min=eps)
    w2, h2 = b[..., 2] - b[..., 0], (b[..., 3] - b[..., 1]).clamp(min=eps)
    cw = torch.max(a[..., 2], b[..., 2]) - torch.min(a[..., 0], b[..., 0])
    ch = torch.max(a[..., 3], b[..., 3]) - torch.min(a[..., 1], b[..., 1])
    c2 = cw**2 + ch**2 + eps
    rho2 = (
        (b[..., 0] + b[..., 2] - a[..., 0] - a[..., 2]) ** 2 + (b[..., 1] + b[..., 3] - a[..., 1] - a[..., 3]) ** 2
    ) / 4
    v = (4 / math.pi**2) * (torch.atan(w2 / h2) - torch.atan(w1 / h1)) ** 2
    with torch.no_grad():
        alpha = v / (v - iou + (1 + eps))
    return iou - (rho2 / c2 + v * alpha)


class TaskAlignedAssigner(nn.Module):
    """Assign anchors to ground truths by the task-aligned metric (TOOD), with a nearest-anchor fallback."""

    def __init__(self, top_k: int = 10, alpha: float = 0.5, beta: float = 6.0, eps: float = 1e-9):
        super().__init__()
        self.top_k, self.alpha, self.beta, self.eps = top_k, alpha, beta, eps

    @torch.no_grad()
    def forward(
        self,
        pred_scores: torch.Tensor,  # (B, A, nc) sigmoid
        pred_boxes: torch.Tensor,  # (B, A, 4) xyxy pixels
        anchors: torch.Tensor,  # (A, 2) pixels
        gt_labels: torch.Tensor,  # (B, M) long
        gt_boxes: torch.Tensor,  # (B, M, 4)
        gt_mask: torch.Tensor,  # (B, M) bool
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return target boxes ``(B, A, 4)``, target scores ``(B, A, nc)``, fg mask ``(B, A)``, gt index ``(B, A)``."""
        b, a, nc = pred_scores.shape
        m = gt_boxes.shape[1]
        if m == 0:
            return (
                torch.zeros_like(pred_boxes),
                torch.zeros_like(pred_scores),
                torch.zeros(b, a, dtype=torch.bool, device=pred_scores.device),
                torch.zeros(b, a, dtype=torch.long, device=pred_scores.device),
            )
        ax, ay = anchors[:, 0].view(1, 1, a), anchors[:, 1].view(1, 1, a)
        x1, y1, x2, y2 = (gt_boxes[..., i : i + 1] for i in range(4))
        inside = (ax > x1) & (ax < x2) & (ay > y1) & (ay < y2)  # (B, M, A)
        centre_d2 = (ax - (x1 + x2) / 2) ** 2 + (ay - (y1 + y2) / 2) ** 2
        nearest = F.one_hot(centre_d2.argmin(-1), a).bool()
        candidates = (inside | nearest) & gt_mask.unsqueeze(-1)

        ious = box_iou_pairs(gt_boxes.unsqueeze(2), pred_boxes.unsqueeze(1)).clamp(0) * candidates  # (B, M, A)
        label_idx = gt_labels.clamp(0, nc - 1).unsqueeze(-1).expand(b, m, a)
        scores = pred_scores.transpose(1, 2).gather(1, label_idx) * candidates  # (B, M, A)
        metric = scores.pow(self.alpha) * ious.pow(self.beta)

        k = min(self.top_k, a)
        top_idx = metric.topk(k, dim=-1).indices
        chosen = torch.zeros_like(candidates).scatter_(-1, top_idx, True) & candidates
        chosen |= nearest & gt_mask.unsqueeze(-1)  # guarantee one positive per gt
        # An anchor claimed by several gts goes to the one it overlaps most.
        multi = chosen.sum(1) > 1  # (B, A)
        if multi.any():
            best = F.one_hot(ious.argmax(1), m).permute(0, 2, 1).bool()
            chosen = torch.where(multi.unsqueeze(1), best & chosen.any(1, keepdim=True), chosen)
        fg = chosen.any(1)
        gt_index = chosen.float().argmax(1)  # (B, A)
        batch_idx = torch.arange(b, device=gt_boxes.device).unsqueeze(-1)
        target_boxes = gt_boxes[batch_idx, gt_index]
        target_labels = gt_labels[batch_idx, gt_index].clamp(0, nc - 1)
        target_scores = F.one_hot(target_labels, nc).float() * fg.unsqueeze(-1)

        metric = metric * chosen
        max_metric = metric.amax(-1, keepdim=True)
        max_iou = (ious * chosen).amax(-1, keepdim=True)
        norm = (metric * max_iou / (max_metric + self.eps)).amax(1)  # (B, A)
        # The guaranteed nearest anchor may have metric 0 early on; give it a small floor.
        norm = torch.where(fg, norm.clamp(min=0.05), norm)
        return target_boxes, target_scores * norm.unsqueeze(-1), fg, gt_index


class DetectionLoss(nn.Module):
    """Sum of the classification (BCE), box (CIoU) and DFL terms, each scaled by its gain."""

    # Buffers (register_buffer), declared for the type checker.
    strides: torch.Tensor
    bins: torch.Tensor

    def __init__(
        self,
        num_classes: int,
        reg_max: int,
        strides: tuple[int, ...],
        box_gain: float = 7.5,
        cls_gain: float = 0.5,
        dfl_gain: float = 1.5,
        top_k: int = 10,
    ):
        super().__init__()
        self.nc, self.reg_max = num_classes, reg_max
        self.register_buffer("strides", torch.tensor(strides, dtype=torch.float32), persistent=False)
        self.register_buffer("bins", torch.arange(reg_max, dtype=torch.float32), persistent=False)
        self.gains = (box_gain, cls_gain, dfl_gain)
        self.assigner = TaskAlignedAssigner(top_k=top_k)

    def forward(self, maps: list[torch.Tensor], targets: list[torch.Tensor]) -> tuple[torch.Tensor, dict[str, float]]:
        """``targets[i]``: ``(M_i, 5)`` rows ``class, x1, y1, x2, y2`` in input pixels for image i."""
        b = maps[0].shape[0]
        flat = torch.cat([m.view(b, m.shape[1], -1) for m in maps], 2).transpose(1, 2)  # (B, A, no)
        box_logits, cls_logits = flat.split((4 * self.reg_max, self.nc), 2)
        anchors, stride = make_anchors(maps, self.strides)  # grid units
        a = anchors.shape[0]
        dist = (box_logits.view(b, a, 4, self.reg_max).softmax(-1) * self.bins).sum(-1)  # (B, A, 4) stride units
        pred_boxes = torch.cat((anchors - dist[..., :2], anchors + dist[..., 2:]), -1) * stride  # pixels

        m = max((len(t) for t in targets), default=0)
        gt = torch.zeros(b, m, 5, device=flat.device)
        gt_mask = torch.zeros(b, m, dtype=torch.bool, device=flat.device)
        for i, t in enumerate(targets):
            if len(t):
                gt[i, : len(t)] = t
                gt_mask[i, : len(t)] = True
        target_boxes, target_scores, fg, _ = self.assigner(
            cls_logits.detach().sigmoid(),
            pred_boxes.detach(),
            anchors * stride,
            gt[..., 0].long(),
            gt[..., 1:],
            gt_mask,
        )
        score_sum = target_scores.sum().clamp(min=1.0)
        loss_cls = F.binary_cross_entropy_with_logits(cls_logits, target_scores, reduction="sum") / score_sum
        if fg.any():
            weight = target_scores.sum(-1)[fg]
            loss_box = ((1.0 - ciou(pred_boxes[fg], target_boxes[fg])) * weight).sum() / score_sum
            anchor_fg = anchors.unsqueeze(0).expand(b, a, 2)[fg]
            stride_fg = stride.unsqueeze(0).expand(b, a, 1)[fg]
            tb = target_boxes[fg] / stride_fg
            ltrb = torch.cat((anchor_fg - tb[:, :2], tb[:, 2:] - anchor_fg), -1).clamp(0, self.reg_max - 1 - 0.01)
            left = ltrb.long()
            wl = (left + 1) - ltrb
            logits = box_logits[fg].view(-1, self.reg_max)
            dfl = F.cross_entropy(logits, left.view(-1), reduction="none").view(-1, 4) * wl + F.cross_entropy(
                logits, (left + 1).view(-1), reduction="none"
            ).view(-1, 4) * (1 - wl)
            loss_dfl = (dfl.mean(-1) * weight).sum() / score_sum
        else:
            loss_box = loss_dfl = flat.sum() * 0.0
        gb, gc, gd = self.gains
        total = (gb * loss_box + gc * loss_cls + gd * loss_dfl) * b
        return total, {
            "box": float(loss_box.detach()),
            "cls": float(loss_cls.detach()),
            "dfl": float(loss_dfl.detach()),
        }
