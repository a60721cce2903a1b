import pytest

from estimator.config import EstimatorConfig, NoiseConfig, ReasonerConfig


def test_defaults_are_the_papers_table_one():
    r = ReasonerConfig()
    assert (r.t_perceived, r.d_sim_perc, r.d_perc_prev, r.horizon) == (0.7, 0.045, 0.032, 0.08)
    assert EstimatorConfig().physics.time_step == pytest.approx(1 / 240)
    assert EstimatorConfig.paper().paper_mode and not EstimatorConfig(particles=8, noise=NoiseConfig()).paper_mode
    assert NoiseConfig.off().is_off and not NoiseConfig().is_off


@pytest.mark.parametrize("make", [
    lambda: ReasonerConfig(d_sim_perc=0),
    lambda: ReasonerConfig(horizon=-1),
    lambda: ReasonerConfig(t_perceived=float("nan")),
    lambda: NoiseConfig(position_std=-0.1),
    lambda: NoiseConfig(friction_range=(1.0, 0.5)),
    lambda: NoiseConfig(param_jitter=1.0),
    lambda: EstimatorConfig(particles=0),
    lambda: EstimatorConfig(workers=-1),
    lambda: EstimatorConfig(resample_threshold=1.5),
    lambda: EstimatorConfig(event_window=0),
])
def test_bad_values_are_rejected(make):
    with pytest.raises(ValueError):
        make()
