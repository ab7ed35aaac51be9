import pytest

from gldt_core.eval.margins import margins_by_sequence


def test_margins_are_ordered_worst_first_and_count_the_sequences_behind() -> None:
    ours = {"b": {"IDF1": 0.5}, "a": {"IDF1": 0.9}, "c": {"IDF1": 0.7}, "only_ours": {"IDF1": 0.0}}
    peer = {"a": {"IDF1": 0.8}, "b": {"IDF1": 0.6}, "c": {"IDF1": 0.7}, "only_peer": {"IDF1": 1.0}}
    result = margins_by_sequence(ours, peer, "IDF1")
    assert result is not None
    assert list(result.margins) == ["b", "c", "a"]  # sequences in one of the two are left out
    assert result.margins["b"] == pytest.approx(-0.1) and result.margins["a"] == pytest.approx(0.1)
    assert result.behind == 1  # a tie (c) is not behind
    assert result.worst == ("b", pytest.approx(-0.1))


def test_a_tie_for_worst_goes_to_the_first_name_and_no_shared_sequence_gives_none() -> None:
    ours = {"z": {"HOTA": 0.4}, "y": {"HOTA": 0.4}}
    peer = {"z": {"HOTA": 0.5}, "y": {"HOTA": 0.5}}
    result = margins_by_sequence(ours, peer, "HOTA")
    assert result is not None and result.worst[0] == "y" and result.behind == 2
    assert margins_by_sequence(ours, {"x": {"HOTA": 0.1}}, "HOTA") is None
