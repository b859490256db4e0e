"""The head's Table 2 row against the statistics row: who beats whom, counted over the attributes defined."""

from __future__ import annotations

from encoders.tagging.versus_statistics import against_statistics, against_statistics_summary, beats_statistics


def cell(metric: str, value: float | None) -> dict[str, object]:
    """A Table 2 cell."""
    return {"metric": metric, "value": value}


def test_beating_the_statistics_means_higher_f1_or_lower_l1_and_ties_do_not() -> None:
    assert beats_statistics(cell("F1", 0.35), cell("F1", 0.30)) is True
    assert beats_statistics(cell("F1", 0.30), cell("F1", 0.30)) is False  # a tie is the constant's answer
    assert beats_statistics(cell("L1", 0.15), cell("L1", 0.19)) is True
    assert beats_statistics(cell("L1", 0.20), cell("L1", 0.19)) is False
    assert beats_statistics(cell("F1", None), cell("F1", None)) is None  # no positive test frame anywhere
    assert beats_statistics(cell("F1", 0.5), cell("F1", None)) is None


def test_the_run_against_the_statistics_counts_the_attributes_defined_on_the_test_logs() -> None:
    result = {
        "inputs": {"none": {"braking": cell("F1", 0.30), "four_way": cell("F1", 0.98), "three_way": cell("F1", None),
                            "pedestrian_density": cell("L1", 0.19)},
                   "both": {"braking": cell("F1", 0.35), "four_way": cell("F1", 0.92), "three_way": cell("F1", None),
                            "pedestrian_density": cell("L1", 0.15)}},
        "skill": {"none": 0.29, "both": 0.40},
        "meta": {"split": "test", "test_logs": ["a", "b"], "frames": 400},
    }
    versus = against_statistics(result)
    assert versus["above_statistics"] == {"braking": True, "four_way": False, "three_way": None,
                                          "pedestrian_density": True}
    assert (versus["above_statistics_count"], versus["defined"]) == (2, 3)  # three-way: no positive test frame
    assert versus["below_statistics"] == ["four_way"]
    assert versus["model"]["braking"] == 0.35 and versus["statistics"]["four_way"] == 0.98
    assert versus["metric"] == {"braking": "F1", "four_way": "F1", "three_way": "F1", "pedestrian_density": "L1"}
    assert versus["skill"] == {"model": 0.40, "statistics": 0.29}
    assert (versus["split"], versus["test_logs"], versus["frames_test"]) == ("test", 2, 400)
    assert against_statistics_summary(versus) == (
        "the tagging head beats the dataset statistics on 2 of the 3 attributes defined on the 2 test log(s) "
        "(skill 0.400 against 0.290; below: four_way)")
