"""The search experiment (experiments.search.experiment): statistics on hand-built rows, paired
tests, a resumable sweep, and the command's errors."""
import json

import numpy as np
import pytest

import experiments.search.experiment as E
from experiments.cli import main
from experiments.evaluation.tracker_report import clopper_pearson
from experiments.search.trial import MAX_LOOKS


def _row(scenario, seed, looks: dict):
    return {"key": f"{scenario}__{seed}", "scenario": scenario, "seed": seed, "target": "cup",
            "methods": {m: {"found": n <= MAX_LOOKS, "looks": n, "cost": 1.5 * n, "first_p": 0.5, "views": [],
                            "planning_ms": 1.0} for m, n in looks.items()}}


def _rows():
    rng = np.random.default_rng(3)
    out = []
    for seed in range(12):
        ref = int(rng.integers(1, 3))
        out.append(_row("a" if seed % 2 else "b", seed, {"closed-loop": ref, "random": ref + int(rng.integers(1, 4)),
                                                        "paper-first": MAX_LOOKS + 1}))
    out.append({"key": "none", "scenario": "a", "seed": 99, "target": None, "methods": {}})  # nothing hidden
    return out


def test_summary_counts_trials_with_a_target_and_gives_exact_binomial_intervals():
    rows = _rows()
    summary = {(r["scenario"], r["method"]): r for r in E.summarize_search(rows)}
    pooled = summary[(E.ALL, "closed-loop")]
    looks = [r["methods"]["closed-loop"]["looks"] for r in rows if r["target"]]
    assert pooled["n"] == 12 and pooled["looks"] == pytest.approx(np.mean(looks))
    assert pooled["looks_lo"] <= pooled["looks"] <= pooled["looks_hi"]
    hits = sum(n <= 1 for n in looks)
    assert pooled["within1"] == pytest.approx(hits / 12)
    assert (pooled["within1_lo"], pooled["within1_hi"]) == pytest.approx(clopper_pearson(hits, 12))
    assert summary[(E.ALL, "paper-first")]["within3"] == 0 and summary[(E.ALL, "paper-first")]["found"] == 0
    assert summary[("a", "random")]["n"] == 6 and ("a", "open-loop") not in summary


def test_paired_tests_compare_the_closed_loop_with_each_other_method():
    tests = {(t["method"], t["metric"]): t for t in E.search_tests(_rows())}
    t = tests[("random", "looks")]
    assert t["n"] == 12 and t["median_diff"] < 0 and t["p_value"] < 0.01  # always fewer looks: 12 of 12
    assert tests[("paper-first", "cost")]["mean_other"] == pytest.approx(1.5 * (MAX_LOOKS + 1))
    text = E.markdown_search(E.summarize_search(_rows()), E.search_tests(_rows()))
    assert "| all scenarios | closed-loop | 12 |" in text and "Wilcoxon" in text


def test_an_interrupted_sweep_keeps_its_rows_and_retries_only_what_is_missing(tmp_path, monkeypatch):
    calls, failed = [], set()

    def fake(spec):
        calls.append(spec.key)
        if spec.seed == 2 and spec.key not in failed:
            failed.add(spec.key)
            raise RuntimeError("exploded")  # fails once, then works
        return {"row": _row(spec.scenario, spec.seed, {"closed-loop": 1, "random": 3}) | {"key": spec.key}}

    monkeypatch.setattr(E, "run_search_trial", fake)
    cfg = E.SearchSweepConfig(("cup_falls_behind_box",), (0, 1, 2), particles=4)
    with pytest.raises(RuntimeError, match="1 of 3"):
        E.run_search_sweep(cfg, tmp_path, workers=1, progress=False)
    path = tmp_path / E.TRIALS_FILE
    assert len(path.read_text().splitlines()) == 2  # the failed trial is not written
    with open(path, "a") as fh:
        fh.write('{"key": "half a li')  # a run killed while writing
    calls.clear()
    rows = E.run_search_sweep(cfg, tmp_path, workers=1, progress=False)
    assert calls == [cfg.trials()[2].key] and [r["seed"] for r in rows] == [0, 1, 2]
    assert [json.loads(x)["seed"] for x in path.read_text().splitlines()] == [0, 1, 2]
    assert (tmp_path / "search_summary.md").exists() and (tmp_path / "search.png").exists()


def test_search_eval_names_an_unknown_scenario(tmp_path, capsys):
    assert main(["search-eval", "--scenarios", "no_such_scenario", "--seeds", "1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no_such_scenario" in err and "cup_falls_behind_box" in err
    assert main(["search-eval", "--seeds", "0", "--out", str(tmp_path)]) == 2
    assert "--seeds" in capsys.readouterr().err
