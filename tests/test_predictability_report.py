"""The predictability report: which scenarios are predictable to 5 cm (per object), and the methods'
success pooled over the predictable ones only."""
import numpy as np
import pytest

from experiments.evaluation.predictability import TwinConfig
from experiments.evaluation.predictability_report import report, summarise


def _twins(name, agreements):
    return [{"key": f"{name}{s}", "scenario": name, "seed": s, "objects": ["a"], "agree": [a],
             "distance_median": [0.01], "agreement": a, "twins": 4, "position_std": 0.001, "param_scale": 0.01}
            for s, a in enumerate(agreements)]


def _trials(name, successes, method="particles", k=64):
    return [{"scenario": name, "seed": s, "method": method, "particles": k, "success_end": v,
             "cover50_hidden": 0.5, "cover90_hidden": 0.9} for s, v in enumerate(successes)]


def test_the_pooled_success_leaves_out_the_unpredictable_scenarios_only():
    twins = _twins("steady", [1.0, 1.0, 0.75]) + _twins("chaotic", [0.25, 0.0, 0.5]) + _twins("tight", [0.9, 0.9, 0.8])
    trials = (_trials("steady", [1.0, 1.0, 0.75]) + _trials("chaotic", [0.0, 0.0, 0.0])
              + _trials("tight", [1.0, 0.5, 1.0, 0.0, 0.0]))  # seeds 3, 4 were not twinned: left out
    s = summarise(twins, trials, threshold=0.85)
    assert {n: v["predictable"] for n, v in s["scenarios"].items()} == {
        "steady": True, "chaotic": False, "tight": True}
    pooled = s["pooled"]["particles (K=64)"]
    assert sorted(pooled["success"]) == sorted([1.0, 1.0, 0.75, 1.0, 0.5, 1.0])
    assert pooled["lowest"] == "tight" and pooled["lowest_success"] == pytest.approx(2.5 / 3)
    text, rows = report(twins, trials, TwinConfig(threshold=0.85))
    assert "left out: `chaotic`" in text
    assert [r["scenario"] for r in rows] == ["chaotic", "steady", "tight"]
    assert rows[0]["predictable"] is False and rows[0]["particles (K=64) cover90"] == pytest.approx(0.9)


def test_one_unpredictable_object_makes_its_scenario_unpredictable():
    # a ball the twins agree on in half the runs, beside a screen and a bin that never move: the
    # scenario's mean agreement is 0.83-0.9, but the ball cannot be located to 5 cm
    rows = [{"key": f"bounce{s}", "scenario": "bounce", "seed": s, "objects": ["screen", "bin", "ball"],
             "agree": [1.0, 1.0, a], "distance_median": [0.0, 0.0, 0.06], "agreement": (2.0 + a) / 3,
             "twins": 10, "position_std": None, "param_scale": 0.01} for s, a in enumerate([0.5, 0.7, 0.6])]
    rows += [{"key": f"box{s}", "scenario": "box", "seed": s, "objects": ["box", "ball"], "agree": [1.0, a],
              "distance_median": [0.0, 0.01], "agreement": (1.0 + a) / 2, "twins": 10, "position_std": None,
              "param_scale": 0.01} for s, a in enumerate([0.9, 0.8, 0.9])]
    trials = _trials("bounce", [1.0, 2 / 3, 1.0]) + _trials("box", [1.0, 0.5, 1.0])
    s = summarise(rows, trials, threshold=0.85)
    assert np.mean(s["scenarios"]["bounce"]["agreement"]) >= 0.85  # the mean alone would call it predictable
    assert s["scenarios"]["bounce"]["least"] == ("ball", pytest.approx(0.6))
    assert s["scenarios"]["bounce"]["predictable"] is False
    assert s["scenarios"]["box"]["least"] == ("ball", pytest.approx(2.6 / 3))
    assert s["scenarios"]["box"]["predictable"] is True
    assert sorted(s["pooled"]["particles (K=64)"]["success"]) == [0.5, 1.0, 1.0]
    text, csv_rows = report(rows, trials, TwinConfig(threshold=0.85))
    assert "left out: `bounce`" in text and "| ball: 60 [" in text
    assert csv_rows[0]["least_object"] == "ball" and csv_rows[0]["least_agreement"] == pytest.approx(0.6)
