"""STFF and motion-aware attention (paper eqs. 1-8), checked against a loop-by-window reference."""

from __future__ import annotations

import pytest
import torch

from gldt_core.training.stff import (
    ALPHA_INIT,
    STFF,
    MotionAwareAttention,
    window_coordinates,
    window_partition,
    window_reverse,
)

# Single-threaded: on shared CPUs OpenMP barriers make multi-threaded small ops much slower.
torch.set_num_threads(1)


def reference_stff(module: STFF, x_t: torch.Tensor, x_prev: torch.Tensor) -> torch.Tensor:
    """Eqs. 1-8 written out with explicit loops over windows and positions (independent of the module's reshapes)."""
    att = module.attention
    b, c, h, w = x_t.shape
    s = att.window
    heads, dk, dm = att.num_heads, c // att.num_heads, att.motion_dim
    coords = []
    for iy in range(s):
        for ix in range(s):
            coords.append([-1 + 2 * ix / (s - 1), -1 + 2 * iy / (s - 1)] if s > 1 else [0.0, 0.0])
    e_pos = torch.tensor(coords) @ att.pos.weight.T + att.pos.bias  # (S2, dm)
    x_app = torch.zeros_like(x_t)
    x_motion = torch.zeros(b, dm, h, w)
    for bi in range(b):
        for wy in range(0, h, s):
            for wx in range(0, w, s):
                cur = x_t[bi, :, wy : wy + s, wx : wx + s].permute(1, 2, 0).reshape(-1, c)  # row-major positions
                prev = x_prev[bi, :, wy : wy + s, wx : wx + s].permute(1, 2, 0).reshape(-1, c)
                q = cur @ att.q.weight.T + att.q.bias  # eq. 6
                kv = prev @ att.kv.weight.T + att.kv.bias
                k, v = kv[:, :c], kv[:, c:]
                app_parts, motion_parts = [], []
                for hd in range(heads):
                    sl = slice(hd * dk, (hd + 1) * dk)
                    a = torch.softmax(q[:, sl] @ k[:, sl].T / dk**0.5, dim=-1)  # eq. 7
                    app_parts.append(a @ v[:, sl])  # eq. 8
                    ms = slice(hd * dm // heads, (hd + 1) * dm // heads)
                    motion_parts.append(a @ e_pos[:, ms] - e_pos[:, ms])  # eq. 8
                app = torch.cat(app_parts, 1).T.reshape(c, s, s)
                mot = torch.cat(motion_parts, 1).T.reshape(dm, s, s)
                x_app[bi, :, wy : wy + s, wx : wx + s] = app
                x_motion[bi, :, wy : wy + s, wx : wx + s] = mot
    gate = torch.sigmoid(
        torch.einsum("oc,bchw->bohw", module.gate.weight[:, :, 0, 0], x_motion) + module.gate.bias.view(1, -1, 1, 1)
    )  # eq. 1
    x_align = x_prev * gate  # eq. 2
    stacked = torch.cat((x_t, x_app, x_align), 1)
    logits = torch.einsum("oc,bchw->bohw", module.fusion.weight[:, :, 0, 0], stacked) + module.fusion.bias.view(
        1, -1, 1, 1
    )
    weights = torch.softmax(logits, 1)  # eq. 3
    x_f = weights[:, 0:1] * x_t + weights[:, 1:2] * x_app + weights[:, 2:3] * x_align  # eq. 4
    return module.alpha * x_f + (1 - module.alpha) * x_t  # eq. 5


@pytest.mark.parametrize("heads,window,motion_dim", [(1, 4, 8), (2, 2, 4), (4, 4, 8)])
def test_stff_matches_equations(heads: int, window: int, motion_dim: int) -> None:
    torch.manual_seed(heads * 10 + window)
    module = STFF(8, window=window, num_heads=heads, motion_dim=motion_dim).eval()
    with torch.no_grad():
        module.alpha.fill_(0.7)  # make the fused branch dominant so errors in it show
        x_t, x_prev = torch.randn(2, 8, 8, 12), torch.randn(2, 8, 8, 12)
        assert torch.allclose(module(x_t, x_prev), reference_stff(module, x_t, x_prev), atol=1e-5)


def test_alpha_initialised_to_table_value_and_learnable() -> None:
    module = STFF(16)
    assert ALPHA_INIT == 0.1
    assert float(module.alpha.detach()) == pytest.approx(0.1)
    assert module.alpha.requires_grad
    x_t, x_prev = torch.randn(1, 16, 8, 8, requires_grad=True), torch.randn(1, 16, 8, 8)
    module(x_t, x_prev).pow(2).sum().backward()
    assert module.alpha.grad is not None and float(module.alpha.grad.abs()) > 0


def test_alpha_zero_returns_current_features() -> None:
    module = STFF(8, window=4)
    with torch.no_grad():
        module.alpha.zero_()
        x_t, x_prev = torch.randn(1, 8, 8, 8), torch.randn(1, 8, 8, 8)
        assert torch.equal(module(x_t, x_prev), x_t)


def test_attention_stays_inside_windows() -> None:
    """Changing the previous frame inside one window must not change any other window's output."""
    torch.manual_seed(0)
    module = STFF(8, window=4).eval()
    with torch.no_grad():
        module.alpha.fill_(1.0)
        x_t, x_prev = torch.randn(1, 8, 8, 8), torch.randn(1, 8, 8, 8)
        base = module(x_t, x_prev)
        changed = x_prev.clone()
        changed[:, :, 0:4, 4:8] += 3.0  # top-right window only
        diff = (module(x_t, changed) - base).abs().sum(1)[0]
    assert diff[0:4, 4:8].min() > 0
    mask = torch.ones(8, 8, dtype=torch.bool)
    mask[0:4, 4:8] = False
    assert float(diff[mask].max()) == 0.0


def test_motion_feature_encodes_displacement() -> None:
    """With sharp attention, a feature that moved by one pixel yields E_pos(p') - E_pos(p), and 0 when static."""
    s, c = 4, 16
    att = MotionAwareAttention(c, window=s, num_heads=1, motion_dim=2)
    with torch.no_grad():
        att.q.weight.copy_(torch.eye(c) * 30), att.q.bias.zero_()
        att.kv.weight.zero_(), att.kv.bias.zero_()
        att.kv.weight[:c].copy_(torch.eye(c) * 30)
        att.pos.weight.copy_(torch.eye(2)), att.pos.bias.zero_()  # E_pos = normalised (x, y)
        # A distinct one-hot "signature" per position of the window.
        feats = torch.eye(c).T.reshape(c, s, s).unsqueeze(0)
        _, static = att(feats, feats)
        assert static.abs().max() < 1e-4
        prev = torch.roll(feats, shifts=1, dims=3)  # content was one column to the right earlier
        _, moved = att(feats, prev)
    step = 2.0 / (s - 1)
    # Columns 0..2 find their match one column to the right: x displacement +step, y 0.
    assert torch.allclose(moved[0, 0, :, :3], torch.full((s, 3), step), atol=1e-3)
    assert torch.allclose(moved[0, 1, :, :3], torch.zeros(s, 3), atol=1e-3)


def test_fusion_weights_are_a_softmax_over_three_sources() -> None:
    module = STFF(8, window=4)
    x = torch.randn(2, 24, 8, 8)
    weights = torch.softmax(module.fusion(x), 1)
    assert module.fusion.out_channels == 3 and module.fusion.kernel_size == (1, 1)
    assert torch.allclose(weights.sum(1), torch.ones(2, 8, 8), atol=1e-6)
    assert module.gate.kernel_size == (1, 1) and module.gate.out_channels == 8


def test_window_partition_roundtrip_and_coordinates() -> None:
    x = torch.randn(2, 5, 8, 12)
    tokens = window_partition(x, 4)
    assert tokens.shape == (2 * 2 * 3, 16, 5)
    assert torch.equal(window_reverse(tokens, 4, 2, 8, 12), x)
    assert torch.equal(tokens[0, :, 0], x[0, 0, 0:4, 0:4].reshape(-1))
    coords = window_coordinates(4)
    assert coords.shape == (16, 2) and float(coords.min()) == -1.0 and float(coords.max()) == 1.0


def test_window_partition_matches_the_six_dim_permute_of_the_paper_layout() -> None:
    """The 4-D form (kept for onnxruntime's speed) orders tokens exactly as one 6-D permute does."""
    b, c, h, w, s = 2, 3, 12, 20, 4
    x = torch.randn(b, c, h, w)
    reference = x.view(b, c, h // s, s, w // s, s).permute(0, 2, 4, 3, 5, 1).reshape(-1, s * s, c)
    assert torch.equal(window_partition(x, s), reference)
    tokens = torch.randn(b * (h // s) * (w // s), s * s, c)
    back = tokens.view(b, h // s, w // s, s, s, c).permute(0, 5, 1, 3, 2, 4).reshape(b, c, h, w)
    assert torch.equal(window_reverse(tokens, s, b, h, w), back)


def test_bad_shapes_are_rejected() -> None:
    module = STFF(8, window=4)
    with pytest.raises(ValueError, match="not divisible by window 4"):
        module(torch.randn(1, 8, 6, 8), torch.randn(1, 8, 6, 8))
    with pytest.raises(ValueError, match="equal shapes"):
        module(torch.randn(1, 8, 8, 8), torch.randn(1, 8, 4, 8))
    with pytest.raises(ValueError, match="divisible by num_heads"):
        STFF(6, num_heads=4)
