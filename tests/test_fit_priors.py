"""Fitting the held-object priors from the per-run counts: the threshold between held and let-go
descents, a tally's fit (Laplace's rule) and its held-out log-likelihood, and the ``fit-priors``
command on one engine and on two."""
from types import SimpleNamespace

import numpy as np
import pytest

from experiments.cli.fit import seed_range as _seed_range
from experiments.evaluation.fit_counts import Counts, Spread
from experiments.evaluation.fit_priors import best_threshold


def test_the_command_fits_with_the_configuration_it_is_given(tmp_path, capsys):
    """``fit-priors --config FILE`` replays the estimator's memory with that file's hands: raw hands
    and one-frame offsets put a carried cup farther from where it is than the filtered defaults
    (a carry behind a box, one seed); a bad field is named with its file."""
    import json

    from experiments.cli.fit import run_fit
    from physics.errors import ConfigError
    raw = tmp_path / "raw.yaml"
    raw.write_text("hands: {filtered: false}\n")
    spreads = {}
    for name, config in (("filtered", None), ("raw", str(raw))):
        args = SimpleNamespace(scenarios="cup_carried_behind_box", seeds="100-100", regions=False, particles=64,
                               workers=1, samples=None, config=config)
        assert run_fit(args) == 0
        spreads[name] = json.loads(capsys.readouterr().out)["held_offset_std"]
    assert spreads["filtered"] < spreads["raw"]
    bad = tmp_path / "bad.yaml"
    bad.write_text("hands:\n  offset_gate: -1\n")
    with pytest.raises(ConfigError, match="bad.yaml:2"):
        run_fit(SimpleNamespace(scenarios="cup_carried_behind_box", seeds="100-100", regions=False, particles=64,
                                workers=1, samples=None, config=str(bad)))


def test_seed_range_is_checked():
    assert list(_seed_range("100-102")) == [100, 101, 102] and list(_seed_range("7")) == [7]
    with pytest.raises(ValueError, match="--seeds"):
        _seed_range("a-b")


def test_best_threshold_separates_the_two_kinds_in_the_middle_of_the_gap():
    assert best_threshold([1.0, 2.0, 3.0], [8.0, 9.0]) == (5.5, 0)
    # overlapping: one error at best; the first run of best intervals is [2, 4)
    assert best_threshold([1.0, 2.0, 5.0], [4.0, 9.0]) == (3.0, 1)
    # one kind only: just past its extreme
    assert best_threshold([], [4.0, 9.0]) == (3.5, 0)
    assert best_threshold([1.0, 2.0], []) == (2.5, 0)
    with pytest.raises(ValueError):
        best_threshold([], [])


def test_held_out_log_likelihood_is_best_for_the_runs_own_fit():
    from experiments.evaluation.fit_priors import Tally, fitted, held_out

    a, b = Tally(), Tally()
    a.occluded, b.occluded = Counts(2, 20), Counts(12, 20)
    a.spread, b.spread = Spread(3 * 100 * 0.01 ** 2, 100), Spread(3 * 100 * 0.03 ** 2, 100)
    fit_a = fitted(a, [], [])
    out = held_out(fit_a, b)
    p_a, p_b = fit_a["hand_occlusion"], 13 / 22
    assert p_a == round(3 / 22, 3)  # Laplace's rule
    ll = (12 * np.log(p_a) + 8 * np.log(1 - p_a)) / 20
    assert out["hand_occlusion"]["ll"] == pytest.approx(ll, abs=1e-4)
    assert out["hand_occlusion"]["ll_own"] == pytest.approx((12 * np.log(p_b) + 8 * np.log(1 - p_b)) / 20, abs=2e-3)
    assert out["hand_occlusion"]["ll"] < out["hand_occlusion"]["ll_own"]
    assert out["held_offset_std"]["ll"] < out["held_offset_std"]["ll_own"]
    assert "release_on_loss_still" not in out  # no samples there
    both = a.merge(b)
    assert (both.occluded.hits, both.occluded.n) == (14, 40) and both.spread.n == 200


def test_the_command_fits_on_both_engines_and_reports_held_out_fits(capsys):
    import json

    from experiments.cli.fit import run_fit
    args = SimpleNamespace(scenarios="cup_carried_behind_box", seeds="100-100", regions=False, particles=64,
                           workers=1, samples=None, config=None, engines="bullet,mujoco")
    assert run_fit(args) == 0
    fit = json.loads(capsys.readouterr().out)
    assert fit["engines"] == ["bullet", "mujoco"] and set(fit["by_engine"]) == {"bullet", "mujoco"}
    assert set(fit["held_out"]) == {"bullet->mujoco", "mujoco->bullet"}
    for direction in fit["held_out"].values():
        for prior in direction.values():
            if "ll" in prior:
                assert prior["ll"] <= prior["ll_own"] + 1e-9  # the runs' own fit is the best there is
    with pytest.raises(ValueError, match="--engines"):
        run_fit(SimpleNamespace(**{**vars(args), "engines": "ode"}))
