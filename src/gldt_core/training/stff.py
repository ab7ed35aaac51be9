"""STFF: spatio-temporal feature fusion of the current and previous frame (paper eqs. 1-8).

A drone that is a dozen pixels wide is often indistinguishable from a bird or a speck of cloud in
one frame; its motion against the background is what gives it away. STFF lets each backbone stage
of the current frame look at a small window of the previous frame's features:

* :class:`MotionAwareAttention` (eqs. 6-8): inside non-overlapping ``S x S`` windows, queries come
  from the current frame, keys/values from the previous frame. ``X_app = A V`` carries the matched
  appearance, ``X_motion = A E_pos - E_pos`` the attention-weighted displacement encoded through a
  linear projection of normalised window coordinates.
* :class:`STFF` (eqs. 1-5): a 1x1 conv + sigmoid turns the motion feature into a gate ``G`` that
  aligns the previous features, a 1x1 conv + softmax produces three fusion weight maps over
  ``[X_t; X_app; X_align]``, and a learnable ``alpha`` (initialised to 0.1, paper Table I) mixes the
  fused feature back into the current one so training starts close to a single-frame network.
"""

from __future__ import annotations

import torch
from torch import nn

#: Initial value of the residual mixing coefficient alpha (paper Table I).
ALPHA_INIT = 0.1


def window_partition(x: torch.Tensor, window: int) -> torch.Tensor:
    """Split ``(B, C, H, W)`` into ``(B * nWin, S*S, C)`` token sequences, one per window.

    Tokens run window by window (row-major over windows), row-major inside a window. Written as
    two 4-D permutes (to NHWC, then swap the window-row and in-window-row axes over contiguous
    ``S*C`` blocks) rather than one 6-D permute: onnxruntime's CPU Transpose moves a 6-D permute
    element by element, and at the P2 level that one op (4 per STFF) cost more than the attention
    itself. The outputs are identical; the timings are in ``docs/experiment-log.md``.
    """
    b, c, h, w = x.shape
    x = x.permute(0, 2, 3, 1).reshape(b * (h // window), window, w // window, window * c)
    return x.permute(0, 2, 1, 3).reshape(-1, window * window, c)


def window_reverse(tokens: torch.Tensor, window: int, b: int, h: int, w: int) -> torch.Tensor:
    """Inverse of :func:`window_partition`: ``(B * nWin, S*S, C)`` back to ``(B, C, H, W)``."""
    c = tokens.shape[-1]
    x = tokens.reshape(b * (h // window), w // window, window, window * c).permute(0, 2, 1, 3)
    return x.reshape(b, h, w, c).permute(0, 3, 1, 2)


def window_coordinates(window: int) -> torch.Tensor:
    """Normalised ``(S*S, 2)`` (x, y) coordinates in [-1, 1] of the positions inside one window."""
    axis = torch.linspace(-1.0, 1.0, window) if window > 1 else torch.zeros(1)
    yy, xx = torch.meshgrid(axis, axis, indexing="ij")
    return torch.stack((xx.reshape(-1), yy.reshape(-1)), dim=-1)


class MotionAwareAttention(nn.Module):
    """Windowed cross-frame attention returning ``(X_app, X_motion)`` (paper eqs. 6-8).

    ``dim`` is the channel count C, ``window`` the window side S, ``num_heads`` N_heads (so
    ``d_k = C / N_heads``) and ``motion_dim`` dim_m, the width of the positional encoding and so of
    ``X_motion``; it is split evenly across heads so each head reports its own displacement.
    """

    def __init__(self, dim: int, window: int = 8, num_heads: int = 1, motion_dim: int = 16):
        super().__init__()
        if dim % num_heads:
            raise ValueError(f"STFF channels {dim} must be divisible by num_heads {num_heads}")
        if motion_dim % num_heads:
            raise ValueError(f"STFF motion_dim {motion_dim} must be divisible by num_heads {num_heads}")
        if window < 1:
            raise ValueError(f"STFF window must be >= 1, got {window}")
        self.dim = dim
        self.window = window
        self.num_heads = num_heads
        self.head_dim = dim // num_heads
        self.motion_dim = motion_dim
        self.scale = self.head_dim**-0.5  # 1 / sqrt(d_k), d_k = C / N_heads (eq. 7)
        self.q = nn.Linear(dim, dim)  # W_q
        self.kv = nn.Linear(dim, 2 * dim)  # W_kv
        self.pos = nn.Linear(2, motion_dim)  # linear projection of normalised coordinates -> E_pos
        self.register_buffer("coords", window_coordinates(window), persistent=False)

    def forward(self, x_t: torch.Tensor, x_prev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Return ``X_app`` ``(B, C, H, W)`` and ``X_motion`` ``(B, dim_m, H, W)``."""
        if x_t.shape != x_prev.shape:
            raise ValueError(f"STFF needs equal shapes, got {tuple(x_t.shape)} and {tuple(x_prev.shape)}")
        b, c, h, w = x_t.shape
        s = self.window
        if h % s or w % s:
            raise ValueError(f"STFF feature map {h}x{w} is not divisible by window {s}")
        tokens_t = window_partition(x_t, s)  # (BW, S2, C)
        tokens_p = window_partition(x_prev, s)
        bw, n, _ = tokens_t.shape
        q = self.q(tokens_t).view(bw, n, self.num_heads, self.head_dim).transpose(1, 2)
        k, v = self.kv(tokens_p).view(bw, n, 2, self.num_heads, self.head_dim).permute(2, 0, 3, 1, 4).unbind(0)
        attn = torch.softmax((q @ k.transpose(-2, -1)) * self.scale, dim=-1)  # (BW, heads, S2, S2)
        x_app = (attn @ v).transpose(1, 2).reshape(bw, n, c)
        e_pos = self.pos(self.coords).view(n, self.num_heads, self.motion_dim // self.num_heads).transpose(0, 1)
        x_motion = (attn @ e_pos - e_pos).transpose(1, 2).reshape(bw, n, self.motion_dim)
        return window_reverse(x_app, s, b, h, w), window_reverse(x_motion, s, b, h, w)


class STFF(nn.Module):
    """Gated alignment + softmax fusion + alpha residual over one backbone stage (eqs. 1-5)."""

    def __init__(self, dim: int, window: int = 8, num_heads: int = 1, motion_dim: int = 16, alpha: float = ALPHA_INIT):
        super().__init__()
        self.attention = MotionAwareAttention(dim, window, num_heads, motion_dim)
        self.gate = nn.Conv2d(motion_dim, dim, 1)  # eq. 1
        self.fusion = nn.Conv2d(3 * dim, 3, 1)  # eq. 3: one weight map per source
        self.alpha = nn.Parameter(torch.tensor(float(alpha)))  # eq. 5, learnable

    def forward(self, x_t: torch.Tensor, x_prev: torch.Tensor) -> torch.Tensor:
        x_app, x_motion = self.attention(x_t, x_prev)
        gate = torch.sigmoid(self.gate(x_motion))  # eq. 1
        x_align = x_prev * gate  # eq. 2
        weights = torch.softmax(self.fusion(torch.cat((x_t, x_app, x_align), 1)), dim=1)  # eq. 3
        x_f = weights[:, 0:1] * x_t + weights[:, 1:2] * x_app + weights[:, 2:3] * x_align  # eq. 4
        return self.alpha * x_f + (1.0 - self.alpha) * x_t  # eq. 5
