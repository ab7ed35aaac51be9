"""``data.synthetic_share``: the sampling weights that set how often training draws synthetic pairs."""

from __future__ import annotations

import pytest

pytest.importorskip("torch", reason="training is the optional `train` extra")

from gldt_core.training.train import sample_weights  # noqa: E402


def test_no_share_means_every_pair_equally_likely() -> None:
    assert sample_weights(30, 10, None) is None


@pytest.mark.parametrize("share", [0.0, 0.2, 0.5, 0.9, 1.0])
def test_the_synthetic_pairs_get_the_asked_share_of_the_weight_whatever_the_counts(share: float) -> None:
    weights = sample_weights(3737, 960, share)
    assert len(weights) == 3737 + 960
    real, synthetic = sum(weights[:3737]), sum(weights[3737:])
    assert synthetic / (real + synthetic) == pytest.approx(share)
    assert len(set(weights[:3737])) == 1 and len(set(weights[3737:])) == 1  # uniform within each source


def test_the_weighted_sampler_draws_that_share() -> None:
    import torch

    weights = sample_weights(400, 100, 0.5)
    draws = list(
        torch.utils.data.WeightedRandomSampler(
            weights, 20_000, replacement=True, generator=torch.Generator().manual_seed(0)
        )
    )
    synthetic = sum(index >= 400 for index in draws) / len(draws)
    assert synthetic == pytest.approx(0.5, abs=0.02)  # the plain sampler would give 0.2


@pytest.mark.parametrize(
    ("real", "synthetic", "share", "message"),
    [
        (10, 10, 1.5, "within \\[0, 1\\]"),
        (10, 10, -0.1, "within \\[0, 1\\]"),
        (10, 0, 0.5, "no synthetic pairs"),
        (0, 10, 0.5, "no real pairs"),
    ],
)
def test_a_share_that_cannot_be_met_is_an_error_naming_the_key(
    real: int, synthetic: int, share: float, message: str
) -> None:
    with pytest.raises(ValueError, match=message) as caught:
        sample_weights(real, synthetic, share)
    assert "data.synthetic_share" in str(caught.value)


def test_an_all_synthetic_or_all_real_run_may_ask_for_the_share_it_has() -> None:
    assert sample_weights(0, 5, 1.0) == [0.2] * 5
    assert sample_weights(4, 0, 0.0) == [0.25] * 4
