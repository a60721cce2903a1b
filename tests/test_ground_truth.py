import numpy as np
import pytest

from estimator.worlds.resting import REST_SPEED, REST_SPIN
from experiments.simulation.simulator import simulate
from physics.transforms import quat_angle


def test_the_truth_starts_at_rest_a_duck_dropped_onto_the_table_rocks_until_it_stands():
    # mesh_clutter_noisy drops its duck from a nominal height: after the scenario's 0.3 s of settling
    # it still rocked (18 degrees from where it stands in seed 2); the estimator's scene is t = 0
    sim = simulate("mesh_clutter_noisy", seed=2, duration=0.5)
    duck = next(o for o in sim.scene.objects if o.id == "duck")
    end = sim.truth[-1]["objects"]["duck"]
    t = sim.truth[-1]["t"]
    assert np.linalg.norm(np.subtract(end["position"], duck.position)) < REST_SPEED * t
    assert quat_angle(np.array(end["orientation"]), np.array(duck.orientation)) < REST_SPIN * t


def test_the_bullet_truth_gives_a_ball_the_rolling_friction_its_scene_states_on_whatever_it_rests_on():
    """ball_in_moving_box: the ball rests on the box's floor (friction as the variant draws it). Bullet
    would realise the ball's stated rolling friction times that friction; the truth gives Bullet
    the stated value over it, and changes it when the ball comes to rest on the table."""
    from experiments.scenarios import load_scenario
    from experiments.simulation.ground_truth import GroundTruth
    from experiments.simulation.variants import sample_variant

    variant = sample_variant(load_scenario("ball_in_moving_box"), 0)
    ids = variant.scene.object_ids
    ball, box = ids.index("ball"), ids.index("box")
    stated = variant.scene.objects[ball].rolling_friction
    with GroundTruth(variant) as truth:
        truth.settle()
        box_mu = truth.world.get_dynamics(box)["lateral_friction"]
        assert box_mu != 1.0
        assert truth.world.get_dynamics(ball)["rolling_friction"] == pytest.approx(stated / box_mu)
        pose = truth.world.get_poses([ball])
        pose[0, :2] += [0.3, -0.3]  # out of the box, onto the table (friction 1.0)
        truth.world.set_poses(pose, [ball])
        for _ in range(60):
            truth._step()
        assert truth.world.get_dynamics(ball)["rolling_friction"] == pytest.approx(stated / 1.0)
