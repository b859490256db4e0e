"""The report's tag section: the head against the dataset statistics, as ``scenesearch eval`` measured it."""

from __future__ import annotations

from typing import Any

from retrieval.tag_report import statistics_section


def versus() -> dict[str, Any]:
    return {"metric": {"braking": "F1", "four_way": "F1", "three_way": "F1", "pedestrian_density": "L1"},
            "model": {"braking": 0.35, "four_way": 0.92, "three_way": None, "pedestrian_density": 0.15},
            "statistics": {"braking": 0.30, "four_way": 0.98, "three_way": None, "pedestrian_density": 0.19},
            "above_statistics": {"braking": True, "four_way": False, "three_way": None, "pedestrian_density": True},
            "above_statistics_count": 2, "defined": 3, "below_statistics": ["four_way"],
            "skill": {"model": 0.40, "statistics": 0.29}, "split": "test", "test_logs": 3, "frames_test": 600}


def test_the_section_tables_every_attribute_against_the_statistics() -> None:
    html = "".join(statistics_section(versus()))
    assert "<tr><td>braking</td><td>F1</td><td>0.300</td><td>0.350</td><td>yes</td></tr>" in html
    assert "<tr><td>four_way</td><td>F1</td><td>0.980</td><td>0.920</td><td>no</td></tr>" in html
    assert "<tr><td>pedestrian_density</td><td>L1</td><td>0.190</td><td>0.150</td><td>yes</td></tr>" in html
    # No positive test frame: F1 undefined for both.
    assert "<tr><td>three_way</td><td>F1</td><td>n/a</td><td>n/a</td><td>n/a</td></tr>" in html
    assert html.count("<tr>") == 5  # the header and a row per attribute
    assert "2 of the 3 attributes defined on the 3 test log(s)" in html and "below: four_way" in html


def test_without_the_figures_there_is_no_section() -> None:
    assert statistics_section(None) == [] and statistics_section({}) == []
