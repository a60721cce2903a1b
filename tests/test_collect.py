"""estimator.collect: the belief of each update, its particle count and the timeline it records."""
import numpy as np

from estimator.config import EstimatorConfig, NoiseConfig, with_adaptive_count
from estimator.filter import SceneEstimator
from estimator.observations import Frame
from helpers import TABLE_TOP, det, table_scene


def _run(config):
    box = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0, 0, TABLE_TOP + 0.03]}}
    with SceneEstimator(table_scene(box), config, np.random.default_rng(0)) as est:
        beliefs = est.run([Frame(0.04 * i, {"box": det([0.0, 0.0, TABLE_TOP + 0.03])}) for i in range(8)])
        return beliefs, est.timeline, est.collect.timeline


def test_the_belief_and_the_timeline_record_what_the_particles_say():
    beliefs, timeline, collected = _run(EstimatorConfig(particles=8, workers=0, noise=NoiseConfig()))
    assert timeline is collected and len(beliefs) >= 3
    last = beliefs[-1]
    assert last.objects["box"].perceived and last.n_particles == 0  # a fixed count is not reported
    on_table = [r for r in last.relations if (r["predicate"], r["subject"], r["object"]) == ("isOnTop", "box", "table")]
    assert on_table and on_table[0]["p"] > 0.9
    facts = timeline.to_json()
    assert "isPerceived" in str(facts) and "isOnTop" in str(facts)


def test_an_adaptive_count_is_reported_with_each_belief():
    cfg = with_adaptive_count(EstimatorConfig(particles=16, workers=0, noise=NoiseConfig()), 16, 64)
    beliefs, _, _ = _run(cfg)
    assert all(16 <= b.n_particles <= 64 for b in beliefs)
    assert beliefs[-1].to_json()["particles"] == beliefs[-1].n_particles
