"""Fitting the reported position distribution (floor, speed term, Student-t degrees of freedom): on
samples drawn from a known model, and on a short run of the estimator."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.config import config_from_dict
from experiments.cli.fit import run_fit
from experiments.evaluation.fit_regions import (
    LEVELS,
    RegionSamples,
    collect_region_samples,
    fit_regions,
    region_config,
    region_coverage,
)
from physics.errors import InputError


def _samples(rng, n, floor, speed_time, dof, scenarios=2):
    """``n`` samples whose residuals are exactly distributed as the model says: particle covariances
    of 2-10 mm, speeds 0-1 m/s for a third of them (0 otherwise), a Student-t of ``dof`` (inf:
    Gaussian) with covariance particles + floor^2 + (speed_time speed)^2 (no evaluation floor)."""
    sd = rng.uniform(0.002, 0.01, size=n)
    cov = sd[:, None, None] ** 2 * np.eye(3)
    speed = np.where(rng.random(n) < 1 / 3, rng.uniform(0, 1, size=n), 0.0)
    total = cov + (floor ** 2 + (speed_time * speed) ** 2)[:, None, None] * np.eye(3)
    z = np.einsum("nij,nj->ni", np.linalg.cholesky(total), rng.standard_normal((n, 3)))
    if math.isfinite(dof):
        z *= np.sqrt((dof - 2) / rng.chisquare(dof, size=n))[:, None]  # covariance kept: scale (dof - 2) / dof
    # trials of 5 samples each, every trial in one scenario
    trial = np.arange(n) // (5 * scenarios) * scenarios + np.arange(n) % scenarios
    return RegionSamples(z, cov, speed, np.arange(n) % scenarios, tuple(f"s{i}" for i in range(scenarios)), trial)


@pytest.mark.parametrize("dof", [3.0, math.inf])
def test_the_fit_recovers_the_model_the_samples_come_from(dof):
    n = 20000
    samples = _samples(np.random.default_rng(3), n, floor=0.003, speed_time=0.05, dof=dof)
    # at the true values, coverage is the level (binomial, 4 sigma)
    pooled, per = region_coverage(samples, 0.003, 0.05, dof, score_floor_std=0.0)
    band = [4 * math.sqrt(lv * (1 - lv) / n) for lv in LEVELS]
    assert np.all(np.abs(pooled - LEVELS) < band)
    fit = fit_regions(samples, score_floor_std=0.0)
    assert fit["min_scenario_met"] and fit["samples"] == n
    got = [fit["coverage"]["50"], fit["coverage"]["90"]]
    assert np.all(np.abs(np.asarray(got) - LEVELS) < band)
    # the tails tell a t from a Gaussian: the fitted degrees of freedom are the true ones' neighbours
    fitted = math.inf if fit["position_dof"] is None else fit["position_dof"]
    if math.isfinite(dof):
        assert fitted <= 4.0
    else:
        assert fitted >= 10.0
    assert fit["covariance_speed_time"] > 0  # the fast samples need the speed term
    # without the three terms a t's residuals over-fill the 50 % region of the particles' Gaussian
    if math.isfinite(dof):
        assert fit["before"]["90"] < 0.9 - band[1]
    # the fragment is a configuration the estimator takes, with the fitted values
    noise = config_from_dict(region_config(fit)).noise
    assert (noise.covariance_floor_std, noise.covariance_speed_time, noise.position_dof) == \
        (fit["covariance_floor_std"], fit["covariance_speed_time"], fit["position_dof"])


def test_coverage_is_averaged_over_trials_as_the_evaluation_averages_it():
    """Two trials of one scenario: one sample covered, and ten samples none covered. Per trial
    (the evaluation's average) the 90 % coverage is 0.5; pooled over samples it would be 1/11."""
    r = np.zeros((11, 3))
    r[1:, 0] = 1.0  # a metre off: outside any region of centimetres
    cov = np.tile(1e-4 * np.eye(3), (11, 1, 1))
    trial = np.array([0] + [1] * 10)
    samples = RegionSamples(r, cov, np.zeros(11), np.zeros(11, dtype=int), ("s0",), trial)
    pooled, per = region_coverage(samples, 0.001, 0.0, math.inf)
    assert pooled[1] == pytest.approx(0.5) and per[0, 1] == pytest.approx(0.5)
    flat = RegionSamples(r, cov, np.zeros(11), np.zeros(11, dtype=int), ("s0",), np.arange(11))
    assert region_coverage(flat, 0.001, 0.0, math.inf)[0][1] == pytest.approx(1 / 11)


def test_the_fit_scores_the_estimators_own_regions_and_reports_the_evaluations():
    """The estimator's regions are what a user reads: the fit scores them without the evaluation's
    floor, and reports them with it too (more variance: at least the same coverage). A collapsed
    particle set (zero covariance) is scored, not a singular matrix, and no zero floor is fitted."""
    samples = _samples(np.random.default_rng(5), 4000, floor=0.003, speed_time=0.0, dof=math.inf)
    collapsed = RegionSamples(samples.residual, np.zeros_like(samples.cov), samples.speed, samples.scenario,
                              samples.scenarios, samples.trial)
    pooled, _ = region_coverage(collapsed, 0.0, 0.0, math.inf)
    assert np.all(pooled < 0.01)  # regions of (almost) no volume hold (almost) nothing
    fit = fit_regions(collapsed)
    assert fit["coverage"]["90"] > 0.5  # the fitted floor gives the collapsed samples a region
    own, seen = fit["coverage"], fit["as_evaluated"]
    assert seen["50"] >= own["50"] and seen["90"] >= own["90"]


def test_a_scenario_below_the_minimum_is_avoided_when_the_grid_allows():
    rng = np.random.default_rng(4)
    good = _samples(rng, 6000, floor=0.0, speed_time=0.0, dof=math.inf, scenarios=1)
    # a smaller second scenario whose errors have a 7 mm floor the particles do not show
    bad = _samples(rng, 1000, floor=0.007, speed_time=0.0, dof=math.inf, scenarios=1)
    merged = RegionSamples(np.concatenate([good.residual, bad.residual]), np.concatenate([good.cov, bad.cov]),
                           np.concatenate([good.speed, bad.speed]), np.r_[np.zeros(6000, int), np.ones(1000, int)],
                           ("good", "bad"), np.arange(7000))
    free = fit_regions(merged, min_scenario=0.0, score_floor_std=0.0)
    assert free["scenario_coverage"]["bad"][1] < 0.8  # the larger one alone would leave it out
    fit = fit_regions(merged, score_floor_std=0.0)
    assert fit["min_scenario_met"] and fit["scenario_coverage"]["bad"][1] >= 0.8
    assert fit["covariance_floor_std"] > free["covariance_floor_std"]
    # impossible with a grid of one narrow point: reported, and the nearest point returned
    stuck = fit_regions(merged, floors=(0.0,), speed_times=(0.0,), dofs=(math.inf,), score_floor_std=0.0)
    assert not stuck["min_scenario_met"] and stuck["scenario_coverage"]["bad"][1] < 0.8


def test_samples_are_checked_and_an_empty_fit_is_an_error():
    with pytest.raises(ValueError):
        RegionSamples(np.zeros((2, 3)), np.zeros((3, 3, 3)), np.zeros(2), np.zeros(2, int), ("a",), np.arange(2))
    with pytest.raises(ValueError):  # a trial index per sample
        RegionSamples(np.zeros((2, 3)), np.zeros((2, 3, 3)), np.zeros(2), np.zeros(2, int), ("a",), np.arange(3))
    empty = RegionSamples(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0, int), ("a",),
                          np.zeros(0, int))
    with pytest.raises(ValueError, match="no hidden samples"):
        fit_regions(empty)


def test_collected_samples_are_the_hidden_ones_of_a_run_whatever_the_workers(tmp_path, monkeypatch):
    import experiments.evaluation.fit_regions as fit_module

    parts = tmp_path / "parts"
    one = collect_region_samples(["cup_falls_behind_box"], [100], particles=4, workers=1, parts_dir=str(parts))
    two = collect_region_samples(["cup_falls_behind_box"], [100], particles=4, workers=2)
    # each trial's samples were kept as it ended: collected again, they are read back, not run
    part = parts / "cup_falls_behind_box__s100__K4.npz"
    assert part.exists()

    def no_run(job):
        raise AssertionError(f"trial {job} ran again")

    monkeypatch.setattr(fit_module, "_trial_samples", no_run)
    again = collect_region_samples(["cup_falls_behind_box"], [100], particles=4, workers=1, parts_dir=str(parts))
    assert np.array_equal(again.residual, one.residual) and np.array_equal(again.cov, one.cov)
    part.write_bytes(b"cut short")
    with pytest.raises(InputError, match="s100__K4"):
        collect_region_samples(["cup_falls_behind_box"], [100], particles=4, workers=1, parts_dir=str(parts))
    assert len(one.residual) > 10 and one.scenarios == ("cup_falls_behind_box",)
    assert np.all(one.trial == 0)  # one trial: its samples carry its index
    for a, b in ((one.residual, two.residual), (one.cov, two.cov), (one.speed, two.speed)):
        assert np.array_equal(a, b)
    assert np.all(np.isfinite(one.residual)) and np.all(one.speed >= 0)
    # the cup is hidden from the start and falls off the table: it moved in some updates, not all
    assert 0 < np.mean(one.speed > 0.05) < 1


def test_the_command_rejects_bad_counts_and_unknown_scenarios_before_running():
    args = SimpleNamespace(scenarios="all", seeds="100-100", regions=True, particles=0, workers=1, samples=None,
                           config=None)
    with pytest.raises(ValueError, match="--particles"):
        run_fit(args)
    with pytest.raises(ValueError, match="--config"):  # the regions fit is of the defaults
        run_fit(SimpleNamespace(**{**vars(args), "particles": 4, "config": "c.yaml"}))
    with pytest.raises(InputError, match="no_such_scenario"):
        collect_region_samples(["cup_falls_behind_box", "no_such_scenario"], [100], particles=4, workers=2)


def test_samples_saved_are_read_back_and_the_command_refits_from_them_without_running(tmp_path, capsys):
    import json

    samples = _samples(np.random.default_rng(9), 3000, floor=0.003, speed_time=0.05, dof=3.0)
    path = tmp_path / "samples.npz"
    samples.save(path)
    back = RegionSamples.load(path)
    for a, b in ((samples.residual, back.residual), (samples.cov, back.cov), (samples.speed, back.speed),
                 (samples.scenario, back.scenario)):
        assert np.array_equal(a, b)
    assert back.scenarios == samples.scenarios and not (tmp_path / "samples.npz.tmp.npz").exists()
    # an existing file is fitted as it is: no scenario is run (an unknown name would fail if one were)
    args = SimpleNamespace(scenarios="no_such_scenario", seeds="100-100", regions=True, particles=4, workers=1,
                           samples=str(path), config=None)
    assert run_fit(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] == 3000 and out["samples_file"] == str(path) and "seeds" not in out
    assert out["position_dof"] == fit_regions(samples)["position_dof"]
    (tmp_path / "bad.npz").write_bytes(b"not an npz")
    with pytest.raises(InputError, match="bad.npz"):
        RegionSamples.load(tmp_path / "bad.npz")
