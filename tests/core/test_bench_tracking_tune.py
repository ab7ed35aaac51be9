"""``gldt bench tracking-tune``: its grid, and that it never touches a held-out profile."""

from __future__ import annotations

import pytest

from gldt_core.bench.tracking_tune import parse_grid, tuning_profile_names
from gldt_core.eval.streams import HELD_OUT, PROFILES


def test_grid_is_every_combination_typed_like_the_config() -> None:
    variants = parse_grid("t_h=0.4,0.5; use_pmr=false,true; history_len=20")
    assert len(variants) == 4
    assert {v["t_h"] for v in variants} == {0.4, 0.5}
    assert {v["use_pmr"] for v in variants} == {False, True}
    assert all(v["history_len"] == 20 and isinstance(v["history_len"], int) for v in variants)


@pytest.mark.parametrize(("grid", "named"), [("nope=1", "nope"), ("t_h=abc", "t_h"), ("t_h=", "t_h"), ("", "no field")])
def test_a_bad_grid_is_one_line_naming_it(grid: str, named: str) -> None:
    with pytest.raises(ValueError, match=named) as error:
        parse_grid(grid)
    assert "\n" not in str(error.value)


def test_only_tuning_profiles_are_tuned_on() -> None:
    names = tuning_profile_names()
    held_out = {p.name for p in PROFILES if p.role == HELD_OUT} | {"real-detector-val_b"}
    assert names and not set(names) & held_out
    assert "real-detector-val" in names
