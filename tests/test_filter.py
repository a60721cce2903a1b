"""The estimator in paper mode (one world, no noise): the behaviours of the IROS 2019 reasoner."""
import json
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from actions.modes import FREE
from estimator.config import EstimatorConfig, reasoning_due
from estimator.filter import SceneEstimator
from estimator.observations import Detection, Frame
from helpers import TABLE_TOP, det, frames, table_scene

HZ = 30.0
BOX = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "mass": 0.2}


def run(scene, frs, config=None):
    with SceneEstimator(scene, config or EstimatorConfig.paper()) as est:
        beliefs = est.run(frs)
        return beliefs, est.timeline.to_json()


def times(duration):
    return np.arange(0.0, duration, 1.0 / HZ)


def smooth(t, t0, t1, a, b):
    s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return a + (b - a) * (3 * s * s - 2 * s ** 3)


def test_box_perceived_floating_rests_on_table_and_is_plausible():
    rest = TABLE_TOP + 0.03
    beliefs, tl = run(table_scene(BOX), frames(times(1.5), lambda t: {"box": [0.1, 0.0, rest + 0.015]}))
    last = beliefs[-1].objects["box"]
    assert last.position[2] == pytest.approx(rest, abs=2e-3)  # the simulated pose, not the perceived one
    assert last.p_plausible == 1.0 and last.p_held == 0.0 and last.perceived
    assert np.all(last.position_cov == 0)
    assert beliefs[-1].relation_p("box", "isOnTop", "table") == 1.0
    assert tl["events"] == []


def test_box_lifted_into_mid_air_is_picked_and_placed():
    rest = TABLE_TOP + 0.03 + 0.01

    def z(t):
        return smooth(t, 0.5, 1.1, rest, rest + 0.25) if t < 1.8 else smooth(t, 1.8, 2.4, rest + 0.25, rest)

    beliefs, tl = run(table_scene(BOX), frames(times(3.2), lambda t: {"box": [0.1, 0.0, z(t)]}))
    by_t = {round(b.t, 3): b for b in beliefs}
    mid = [b for b in beliefs if 1.2 <= b.t <= 1.7]
    assert mid and all(b.objects["box"].p_plausible == 0.0 for b in mid)
    for b in mid:  # implausible: output at the perceived pose
        assert b.objects["box"].position[2] == pytest.approx(z(b.t), abs=1e-9)
    events = [(e["action"], e["t"]) for e in tl["events"]]
    assert [a for a, _ in events] == ["Pick", "Place"]
    assert 0.5 < events[0][1] < 1.3 and 2.2 < events[1][1] < 2.8
    end = beliefs[-1].objects["box"]
    assert end.p_plausible == 1.0 and end.position[2] == pytest.approx(TABLE_TOP + 0.03, abs=2e-3)
    assert by_t and beliefs[-1].relation_p("box", "isOnTop", "table") == 1.0


def _dragged_box_frames(lift: float, seed: int = 0):
    """A 6 cm box at rest on the table, seen 1 cm too high (a tracker's bias) with 3 mm noise, moved
    30 cm along x between 0.6 and 1.8 s, raised by ``lift`` (m) on the way (0: dragged along the
    table), and left where it ends, in view, until 3.2 s."""
    rng = np.random.default_rng(seed)
    rest = TABLE_TOP + 0.03 + 0.01

    def at(t):
        x = smooth(t, 0.6, 1.8, 0.15, -0.15)
        z = rest + lift * np.sin(np.pi * np.clip((t - 0.6) / 1.2, 0.0, 1.0))
        return {"box": list(np.array([x, 0.0, z]) + rng.normal(0.0, 0.003, 3))}

    return frames(times(3.2), at)


@pytest.mark.parametrize("particles", [1, 16])
def test_a_box_dragged_along_the_table_is_one_push_and_a_lifted_one_a_pick_and_a_place(particles):
    from estimator.config import default_config

    cfg = default_config(particles)
    for lift, expected in ((0.0, ["Push"]), (0.12, ["Pick", "Place"])):
        with SceneEstimator(table_scene(BOX), cfg, np.random.default_rng(1)) as est:
            est.run(_dragged_box_frames(lift))
            tl = est.timeline.to_json()
        events = [(e["action"], e["t"]) for e in tl["events"]]
        assert [a for a, _ in events] == expected, (particles, lift, events)
        assert 0.6 < events[0][1] < 1.3  # when it started moving (its Pick's time), not when let go
        if lift == 0.0:
            assert all(e["p"] > 0.5 for e in tl["events"])
            end = est.last_belief
            assert end.relation_p("box", "isOnTop", "table") > 0.9 and end.objects["box"].p_held < 0.1


def test_a_box_dragged_along_the_table_is_one_push_whatever_the_seed():
    """Physics lets the dragged box slide to rest before the hand stops (the drag slows down), so
    particles hold it again to follow its detections: with ``one_action_per_motion`` that is the
    same Push going on, in every run (without it, about one run in three of these also reported a
    Pick or a second Push: all six would pass by chance with probability (2/3)^6 < 0.1)."""
    from estimator.config import default_config

    for seed in range(6):
        with SceneEstimator(table_scene(BOX), default_config(16), np.random.default_rng(seed)) as est:
            est.run(_dragged_box_frames(0.0, seed=seed % 4))
            actions = [e["action"] for e in est.timeline.to_json()["events"]]
        assert actions == ["Push"], (seed, actions)


@pytest.mark.parametrize("particles", [1, 16])
def test_a_pushed_stack_is_one_push_of_its_base_and_no_event_for_what_rides_on_it(particles):
    """A 5 cm block on a 6 cm box, the box dragged 30 cm along the table in 2.4 s (the block rides on
    it, 1 cm off-centre): in some particles the block diverges from its detections before its box
    does (it does with this seed), but whatever sits on an object perceived moving is carried, so
    its episode is silent (as the simulator's truth has it)."""
    from estimator.config import default_config

    rng = np.random.default_rng(5)
    rest, off = TABLE_TOP + 0.03 + 0.01, 0.01
    block = {"id": "block", "box": {"size": [0.05, 0.05, 0.05]}, "mass": 0.1,
             "pose": {"position": [0.15 + off, 0.0, TABLE_TOP + 0.06 + 0.025]}}

    def at(t):
        x = smooth(t, 0.6, 3.0, 0.15, -0.15)
        noise = rng.normal(0.0, 0.003, (2, 3))
        return {"box": list(np.array([x, 0.0, rest]) + noise[0]),
                "block": list(np.array([x + off, 0.0, rest + 0.055]) + noise[1])}

    scene = table_scene(dict(BOX, pose={"position": [0.15, 0.0, TABLE_TOP + 0.03]}), block)
    with SceneEstimator(scene, default_config(particles), np.random.default_rng(5)) as est:
        est.run(frames(times(4.0), at))
        tl = est.timeline.to_json()
    assert [(e["action"], e["subject"]) for e in tl["events"]] == [("Push", "box")]
    assert est.last_belief.relation_p("block", "isOnTop", "box") > 0.9


def test_unperceived_objects_fall_onto_their_support():
    scene = table_scene(
        {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05},
        {"id": "cup", "cylinder": {"radius": 0.04, "height": 0.1}, "mass": 0.2})

    def seen(t):
        objs = {}
        if t < 1.0:  # held in mid-air beside the table, then hidden
            objs["ball"] = [1.1, 0.0, 0.9]
            objs["cup"] = [0.2, 0.0, TABLE_TOP + 0.05 + 0.2]  # floating 20 cm above the table
        return objs

    beliefs, tl = run(scene, frames(times(3.0), seen))
    end = beliefs[-1].objects
    assert not end["ball"].perceived and not end["cup"].perceived
    assert end["ball"].position[2] == pytest.approx(0.03, abs=3e-3)
    assert end["cup"].position[2] == pytest.approx(TABLE_TOP + 0.05, abs=3e-3)
    assert beliefs[-1].relation_p("ball", "isOnTop", "floor") == 1.0
    assert beliefs[-1].relation_p("cup", "isOnTop", "table") == 1.0
    assert end["ball"].hypotheses[0].relation == "isOnTop" and end["ball"].hypotheses[0].support == "floor"
    actions = [(e["action"], e["subject"]) for e in tl["events"]]
    # still "perceived" for t_perceived = 0.7 s after the last sighting, then let go
    assert ("Release", "ball") in actions and ("Release", "cup") in actions
    rel_t = [e["t"] for e in tl["events"] if e["action"] == "Release"]
    assert all(1.6 <= t <= 1.8 for t in rel_t)


@pytest.mark.parametrize("smooth_motion", [False, True])
def test_moved_container_carries_its_contents_with_rotation(smooth_motion):
    size = [0.3, 0.2, 0.12]
    z = TABLE_TOP + 0.06
    scene = table_scene(
        {"id": "crate", "container": {"size": size, "wall": 0.01}, "mass": 0.7,
         "pose": {"position": [0, 0, z]}},
        {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
         "pose": {"position": [0.08, 0.0, TABLE_TOP + 0.01 + 0.03]}})
    yaw90 = Rotation.from_euler("z", 90, degrees=True).as_quat()

    def seen(t):
        if t < 0.8:
            return {"crate": ([0, 0, z], (0, 0, 0, 1))}
        if not smooth_motion:
            return {"crate": ([0.2, 0.1, z], tuple(yaw90))}
        s = float(np.clip((t - 0.8) / 1.2, 0, 1))
        q = Rotation.from_euler("z", 90 * s, degrees=True).as_quat()
        return {"crate": ([0.2 * s, 0.1 * s, z + 0.1 * np.sin(np.pi * s)], tuple(q))}

    beliefs, _ = run(scene, frames(times(2.8), seen))
    ball = beliefs[-1].objects["ball"]
    assert not ball.perceived
    assert all(b.relation_p("ball", "isIn", "crate") == 1.0 for b in beliefs)
    if not smooth_motion:  # a jump of the perception: the contents are carried rigidly (Alg. 2)
        assert np.allclose(ball.position[:2], [0.2, 0.1 + 0.08], atol=0.01)  # offset rotated 90 deg
    else:  # a carried box: physics moves the ball, which may roll inside the (rotated) crate
        inner = np.array([size[1], size[0]]) / 2 - 0.01 - 0.03 + 0.002
        assert np.all(np.abs(ball.position[:2] - [0.2, 0.1]) <= inner)
        assert ball.position[2] == pytest.approx(TABLE_TOP + 0.01 + 0.03, abs=0.003)


@pytest.mark.parametrize("particles", [1, 16])
def test_a_visible_ball_carried_in_a_crate_gets_no_event_of_its_own(particles):
    from estimator.config import default_config

    z = TABLE_TOP + 0.06
    scene = table_scene(
        {"id": "crate", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01}, "mass": 0.7,
         "pose": {"position": [0, 0, z]}},
        {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
         "pose": {"position": [0.0, 0.0, TABLE_TOP + 0.01 + 0.03]}})
    rng = np.random.default_rng(3)

    def seen(t):  # lifted 10 cm, carried 30 cm and put down; the ball, seen inside, goes with it
        s = float(np.clip((t - 0.6) / 1.5, 0, 1))
        c = np.array([0.3 * s, 0.0, z + 0.1 * np.sin(np.pi * s)])
        return {"crate": list(c + rng.normal(0, 0.003, 3)),
                "ball": list(c + [0.0, 0.0, -0.02] + rng.normal(0, 0.003, 3))}

    with SceneEstimator(scene, default_config(particles), np.random.default_rng(0)) as est:
        est.run(frames(times(3.0), seen))
        tl = est.timeline.to_json()
    assert [(e["action"], e["subject"]) for e in tl["events"]] == [("Pick", "crate"), ("Place", "crate")]


def test_paper_mode_is_deterministic_and_horizon_sets_the_rate():
    scene = table_scene(BOX)
    frs = frames(times(1.0), lambda t: {"box": [0.1, 0.0, TABLE_TOP + 0.05]})
    a, _ = run(scene, frs)
    b, _ = run(scene, frs)
    assert [x.to_json() for x in a] == [x.to_json() for x in b]
    dt = np.diff([x.t for x in a])
    assert np.all(dt >= 0.08 - 1e-9) and np.all(dt <= 0.08 + 1 / HZ + 1e-9)


def test_time_must_increase_and_unknown_ids_are_rejected():
    with SceneEstimator(table_scene(BOX)) as est:
        est.update(Frame(0.0, {"box": det([0, 0, 0.7])}))
        with pytest.raises(ValueError, match="increase"):
            est.update(Frame(0.0, {}))
        with pytest.raises(ValueError, match="unknown object"):
            est.update(Frame(0.1, {"mug": det([0, 0, 0.7])}))


# ---------------------------------------------------------------------------------------------------
# The particle filter: statistics against independent answers, determinism, degenerate cases

from estimator.config import NoiseConfig  # noqa: E402
from physics.scene import scene_from_dict  # noqa: E402
from physics.world import World  # noqa: E402


def test_unseen_free_fall_mean_matches_the_analytic_solution():
    z0, k = 3.0, 64
    scene = scene_from_dict({"objects": [{"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0, 0, z0]}}]})
    # the speed term off: it widens what the particles say by how fast the object went
    cfg = EstimatorConfig(particles=k, noise=NoiseConfig(position_std=0.01, covariance_speed_time=0.0))
    with SceneEstimator(scene, cfg, np.random.default_rng(11)) as est:
        b = est.run([Frame(i / 30, {}) for i in range(16)])[-1]
        z = est.poses[:, 0, 2]
    n, dt = round(b.t * 240), 1 / 240
    exact = z0 - 9.81 * dt * dt * n * (n + 1) / 2  # Bullet's semi-implicit Euler, solved exactly
    assert abs(b.t * 240 - n) < 1e-9 and n == 120
    se = z.std(ddof=1) / np.sqrt(k)
    assert abs(b.objects["ball"].position[2] - exact) < 3 * se
    # the spread: horizontally the prior's (0.01 m, with the process noise's random walk); vertically
    # the random walk (3 mm per sqrt(s) over 0.5 s: 2.1 mm) and the covariance floor (the prior's noise
    # is horizontal: an object is mostly placed on a support)
    cov = b.objects["ball"].position_cov
    floor, walk = cfg.noise.covariance_floor_std, cfg.noise.process_position_std * np.sqrt(0.5)
    assert 0.006 < np.sqrt(cov[0, 0]) < 0.015 and floor < np.sqrt(cov[2, 2]) < np.hypot(floor, 2 * walk)
    assert b.ess == pytest.approx(k)  # nothing was perceived: the weights stay uniform


def test_ball_over_a_ridge_lands_left_or_right_as_brute_force_monte_carlo_says():
    ridge = {"id": "ridge", "static": True, "box": {"size": [0.4, 0.2, 0.2]},
             "pose": {"position": [0, 0, 0], "orientation": [0.3826834, 0, 0, 0.9238795]}}
    start = [0.0, 0.004, 0.4]
    scene = scene_from_dict({"objects": [ridge, {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
                                                 "pose": {"position": start}}]})
    k, n_mc, duration = 64, 256, 1.0
    noise = NoiseConfig(process_position_std=0.0, process_orientation_std=0.0,
                        rolling_friction_range=(0.0, 0.005), spinning_friction_range=(0.0, 0.005))
    with SceneEstimator(scene, EstimatorConfig(particles=k, noise=noise), np.random.default_rng(5)) as est:
        b = est.run([Frame(i / 30, {}) for i in range(int(duration * 30) + 1)])[-1]
        right_pf = float(b.weights @ (est.poses[:, 1, 1] > 0))
        n_steps = round(b.t * 240)
    # brute force: independent worlds, initial state and parameters drawn from the same priors
    rng = np.random.default_rng(99)
    right = 0
    with World(scene) as w:
        canonical = w.save_state()
        base_mass = w.get_dynamics(1)["mass"]
        for _ in range(n_mc):
            w.restore_state(canonical)
            pos = np.asarray(start) + rng.normal(0, noise.position_std, 3)
            w.set_poses(np.concatenate([pos, [0, 0, 0, 1]])[None], [1])
            w.set_velocities(np.zeros((1, 6)), [1])
            w.set_dynamics(1, lateral_friction=rng.uniform(*noise.friction_range),
                           rolling_friction=rng.uniform(*noise.rolling_friction_range),
                           spinning_friction=rng.uniform(*noise.spinning_friction_range),
                           restitution=rng.uniform(*noise.restitution_range),
                           mass=base_mass * rng.uniform(*noise.mass_scale_range))
            w.step(n_steps)
            right += w.get_poses([1])[0, 1] > 0
    p_mc = right / n_mc
    p = (right_pf * k + right) / (k + n_mc)
    band = 3 * np.sqrt(p * (1 - p) * (1 / k + 1 / n_mc))
    assert 0.55 < p_mc < 0.85  # the offset makes the answer non-trivial
    assert abs(right_pf - p_mc) < band


def _run_json(workers):
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}),
                        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08},
                         "pose": {"position": [-0.2, 0.1, TABLE_TOP + 0.2]}})
    cfg = EstimatorConfig(particles=6, workers=workers, noise=NoiseConfig())
    frs = frames(np.arange(0, 2.0, 1 / 30), lambda t: {"box": [0.1, 0.0, smooth(t, 0.4, 0.9, TABLE_TOP + 0.04,
                                                                              TABLE_TOP + 0.3)]} if t < 1.4 else {})
    with SceneEstimator(scene, cfg, np.random.default_rng(3)) as est:
        return [json.dumps(b.to_json()) for b in est.run(frs)], est.timeline.to_json()


def test_same_seed_same_output_whatever_the_number_of_workers():
    a, ta = _run_json(0)
    b, tb = _run_json(1)
    c, tc = _run_json(2)
    assert a == b == c and ta == tb == tc
    assert any('"Pick"' in line for line in a)


def test_a_deferred_resampling_waits_for_finish_and_changes_nothing():
    """step(defer=True) returns the belief before resampling: until finish() (or the next step) the
    state holds the weighed particles the belief was made of; the beliefs and the timeline are those
    of an undeferred run, bit for bit."""
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}),
                        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08},
                         "pose": {"position": [-0.2, 0.1, TABLE_TOP + 0.2]}})
    cfg = EstimatorConfig(particles=6, workers=0, noise=NoiseConfig())
    frs = frames(np.arange(0, 2.0, 1 / 30), lambda t: {"box": [0.1, 0.0, smooth(t, 0.4, 0.9, TABLE_TOP + 0.04,
                                                                              TABLE_TOP + 0.3)]} if t < 1.4 else {})
    expected, timeline = _run_json(0)
    out, deferred = [], 0
    with SceneEstimator(scene, cfg, np.random.default_rng(3)) as est:
        for i, f in enumerate(frs):
            est.observe(f)
            if not reasoning_due(est.t_tick, f.t, cfg.reasoner.horizon):
                continue
            belief = est.step(defer=True)
            out.append(json.dumps(belief.to_json()))
            if est._pending is not None:
                deferred += 1
                weighed = est.state.log_weights.copy()
                assert not np.all(weighed == weighed[0])  # not resampled yet: the weights are unequal
                if i % 2:  # half the time finished here, half by the next step
                    est.finish()
                    assert est._pending is None and np.all(est.state.log_weights == 0.0)
        assert deferred > 0
        assert out == expected and est.timeline.to_json() == timeline


def test_exploded_particles_and_total_weight_collapse_never_give_nan():
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}))
    cfg = EstimatorConfig(particles=4, noise=NoiseConfig())
    with SceneEstimator(scene, cfg, np.random.default_rng(0)) as est:
        real_run = est.pool.run
        mode = {"kill": [0]}

        def corrupt(batch, *a, **kw):
            out = real_run(batch, *a, **kw)
            for k in mode["kill"]:
                out.poses[k] = np.nan
                out.velocities[k] = 1e9
                out.finite[k] = False
            return out

        est.pool.run = corrupt
        beliefs = est.run(frames(np.arange(0, 0.5, 1 / 30), lambda t: {"box": [0.1, 0, TABLE_TOP + 0.04]}))
        assert beliefs[-1].weights[0] < 1e-12 or est.n_updates > 1
        assert est.reseeded == est.n_updates  # particle 0, at every update
        assert np.isfinite(est.poses).all() and np.isfinite(est.log_weights[0])  # it took a survivor's state
        mode["kill"] = [0, 1, 2, 3]
        more = est.run(frames(np.arange(0.5, 1.0, 1 / 30), lambda t: {"box": [0.1, 0, TABLE_TOP + 0.04]}))
        assert est.recoveries >= 1
        mode["kill"] = []
        more += est.run([Frame(1.0 + i / 30, {}) for i in range(6)])  # empty frames
    for b in beliefs + more:
        text = json.dumps(b.to_json())
        assert "NaN" not in text and "Infinity" not in text
        assert np.isfinite(b.ess) and b.ess >= 1.0 - 1e-9
    assert more[-1].objects["box"].position[2] == pytest.approx(TABLE_TOP + 0.03, abs=0.02)


def test_held_object_lost_splits_into_released_and_held_hypotheses():
    scene = table_scene({"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "mass": 0.2})
    hand = np.array([1.0, 0.0, 1.0])
    frs = []
    for t in np.arange(0, 3.0, 1 / 30):
        objs = {"cup": det(hand + [0, 0, -0.05])} if t < 0.8 else {}
        frs.append(Frame(float(t), objs, {"human/right": hand}))  # a still hand: it may have let go
    cfg = EstimatorConfig(particles=32, noise=NoiseConfig())
    with SceneEstimator(scene, cfg, np.random.default_rng(2)) as est:
        b = est.run(frs)[-1]
    cup = b.objects["cup"]
    p_held = b.hypothesis_p("cup", "held", None)
    p_floor = b.hypothesis_p("cup", "isOnTop", "floor")
    p_falling = b.hypothesis_p("cup", "none", None)  # let go late (the hazard), still in the air
    assert cup.p_held == pytest.approx(p_held)
    assert 0.15 < p_held < 0.85 and p_floor > 0.1 and p_held + p_floor + p_falling > 0.95
    held_pos = [h.position for h in cup.hypotheses if h.relation == "held"][0]
    assert np.allclose(held_pos, [1.0, 0.0, 0.95], atol=0.05)  # in the tracked hand


def _flicked_ball(x_cut=-0.25, x0=-0.5, v=0.9):
    """A ball at rest on the table at ``x0`` flicked along x at ``v`` (0.9 m/s) at t = 0.5 s (rolling
    without slipping, a little rolling friction), simulated for 3 s; detected at 30 Hz only while
    x < ``x_cut`` (the camera sees the first part of its path). Returns the scene, the frames, the
    true final position, the time and position of the last detection, and the true position ``(3,)``
    at each frame's time."""
    r = 0.03
    scene = table_scene({"id": "ball", "sphere": {"radius": r}, "mass": 0.05, "rolling_friction": 0.002,
                         "pose": {"position": [x0, 0.0, TABLE_TOP + r]}})
    frs, seen, truth = [], [], {}
    with World(scene) as w:
        n = int(round(1 / HZ / w.settings.time_step))
        for f in range(int(3.0 * HZ)):
            t = f / HZ
            if f == int(0.5 * HZ):
                w.set_velocities(np.array([[v, 0.0, 0.0, 0.0, v / r, 0.0]]), [1])
            pose = w.get_poses([1])[0]
            truth[round(t, 6)] = pose[:3].copy()
            visible = pose[0] < x_cut
            frs.append(Frame(t, {"ball": det(pose[:3], pose[3:])} if visible else {}))
            if visible:
                seen.append((t, pose[:3].copy()))
            w.step(n)
        final = w.get_poses([1])[0, :3]
    return scene, frs, final, seen[-1], truth


def test_a_ball_rolling_out_of_view_goes_on_as_physics_says_and_paper_mode_pins_it():
    scene, frs, final, (t_last, p_last), truth = _flicked_ball()
    assert final[0] - p_last[0] > 0.3  # it rolled on well beyond where it was last seen
    # its rolling friction known (the default prior spreads it over a factor of four, and the
    # stopping point with it): the test is of momentum carried out of view
    cfg = EstimatorConfig(particles=32, noise=NoiseConfig(rolling_friction_scale=None))
    with SceneEstimator(scene, cfg, np.random.default_rng(4)) as est:
        beliefs = est.run(frs)
    ball = beliefs[-1].objects["ball"]
    # it rolled on with its momentum and stopped where physics says, within the belief's spread
    # (the particles' friction and restitution differ) plus the 5 mm perception noise floor
    sd = np.sqrt(np.trace(ball.position_cov) + 3 * 0.005 ** 2)
    assert np.linalg.norm(ball.position - final) < 3 * sd and sd < 0.1
    assert ball.position[0] - p_last[0] > 0.25
    # and it was moving on while it still counted as perceived (the stale detection does not pin it)
    aged = [b for b in beliefs if t_last + 0.2 <= b.t <= t_last + 0.7]
    assert aged and all(b.objects["ball"].perceived for b in aged)
    for b in aged:  # ... within 3 cm of where it is (and 10 cm or more beyond where it was seen)
        true_now = truth[round(b.t, 6)]
        assert true_now[0] - p_last[0] > 0.1
        assert np.linalg.norm(b.objects["ball"].position - true_now) < 0.03
    # paper mode keeps Algorithm 1's rule: perceived within 0.7 s, teleported at rest at its
    # detections, so the ball stops where it was last seen
    with SceneEstimator(scene, EstimatorConfig.paper()) as est:
        paper = est.run(frs)
    pinned = [b for b in paper if t_last <= b.t <= t_last + 0.7]
    assert pinned and all(b.objects["ball"].perceived for b in pinned)
    for b in pinned:
        assert np.allclose(b.objects["ball"].position, p_last, atol=0.005)


def test_an_undetected_moving_object_gets_the_speed_term_and_nothing_else_changes():
    scene, frs, _final, _seen, _truth = _flicked_ball()
    c = 0.1
    runs = []
    for speed_time in (0.0, c):
        noise = NoiseConfig(rolling_friction_scale=None, covariance_speed_time=speed_time)
        cfg = EstimatorConfig(particles=8, noise=noise)
        with SceneEstimator(scene, cfg, np.random.default_rng(6)) as est:
            runs.append(est.run(frs))
    plain, wide = runs
    assert len(plain) == len(wide)
    undetected_moving = 0
    for k in range(1, len(wide)):
        a, b, prev = plain[k].objects["ball"], wide[k].objects["ball"], plain[k - 1].objects["ball"]
        # the term reports; it does not steer: the same positions and hypotheses
        assert np.array_equal(a.position, b.position) and a.p_held == b.p_held
        detected = any(plain[k - 1].t < f.t <= plain[k].t + 1e-9 and "ball" in f.objects for f in frs)
        speed = np.linalg.norm(a.position - prev.position) / (plain[k].t - plain[k - 1].t)
        expected = 0.0 if detected else (c * speed) ** 2
        assert np.allclose(b.position_cov - a.position_cov, expected * np.eye(3), atol=1e-12)
        assert np.allclose(b.mean_position_cov - a.mean_position_cov, expected * np.eye(3), atol=1e-12)
        undetected_moving += (not detected) and speed > 0.1
    assert undetected_moving >= 3  # the ball rolled on, unseen, for several updates


def test_a_ball_seen_rolling_off_the_edge_falls_on_as_its_last_detections_say():
    """A ball rolls off the table's edge (x = 0.76 m) at 1 m/s, seen for the first frames of its fall
    only: it falls on along the free fall through its last detections (their vertical speed kept,
    and the hand-less held hypothesis let go there). At every update of the fall the truth lies in
    the belief's 99 % region (its covariance plus the 5 mm perception floor) and within 10 cm;
    before, every particle took it for held in the air where it was last seen."""
    scene, frs, _final, (t_last, p_last), truth = _flicked_ball(x_cut=0.8, x0=0.3, v=1.0)
    assert TABLE_TOP < p_last[2] < TABLE_TOP + 0.028  # seen leaving the edge, a little fallen
    cfg = EstimatorConfig(particles=16, noise=NoiseConfig(rolling_friction_scale=None))
    with SceneEstimator(scene, cfg, np.random.default_rng(6)) as est:
        beliefs = est.run(frs)
    falling = [b for b in beliefs if t_last < b.t and truth[round(b.t, 6)][2] > 0.1]
    assert len(falling) >= 2
    for b in falling:
        ball = b.objects["ball"]
        e = ball.position - truth[round(b.t, 6)]
        assert e @ np.linalg.solve(ball.position_cov + 0.005 ** 2 * np.eye(3), e) < chi2.ppf(0.99, 3)
        assert np.linalg.norm(e) < 0.1


def test_a_ball_dropped_from_a_tracked_hand_falls_on_at_the_speed_it_was_seen_falling():
    """A tracked hand holds a ball 30 cm above the table and lets go at t = 1 s; the ball is seen
    for the first 15 cm of its fall, then no more (no camera: nothing says where it went), the hand
    still. Let go where it was last seen, it falls on at the free fall's speed there (1.7 m/s), and
    lands when the truth does: from the second update after its last detection on, its height is
    within 2 cm of the truth's. Let go at rest (the hand's speed), it landed an update late."""
    r, drop, g = 0.03, 0.3, 9.81
    scene = table_scene({"id": "ball", "sphere": {"radius": r}, "mass": 0.05, "restitution": 0.0,
                         "pose": {"position": [0.0, 0.0, TABLE_TOP + r]}})
    z_rest, z_top = TABLE_TOP + r, TABLE_TOP + r + drop

    def true_z(t):
        return max(z_top - 0.5 * g * max(t - 1.0, 0.0) ** 2, z_rest) if t >= 0.3 else z_rest

    frs = []
    for t in np.arange(0.0, 2.0, 1 / HZ):
        hand = np.array([0.0, 0.0, z_top + 0.06])
        z = true_z(t) if t >= 0.3 else z_rest
        seen = z > z_top - 0.15 or t < 0.3
        frs.append(Frame(float(t), {"ball": Detection(np.array([0.0, 0.0, z]))} if seen else {},
                         {"human/right": hand} if t >= 0.2 else {}))
    t_last = max(f.t for f in frs if "ball" in f.objects)
    cfg = EstimatorConfig(particles=8, noise=NoiseConfig(rolling_friction_scale=None))
    with SceneEstimator(scene, cfg, np.random.default_rng(3)) as est:
        beliefs = est.run(frs)
    after = [b for b in beliefs if t_last + 0.1 < b.t <= t_last + 0.6]
    assert len(after) >= 3
    for b in after:
        assert abs(b.objects["ball"].position[2] - true_z(b.t)) < 0.02, (b.t, b.objects["ball"].position, true_z(b.t))
    assert after[-1].objects["ball"].p_held < 0.2


def test_velocities_the_model_sets_after_physics_reach_the_worlds(monkeypatch):
    """What the model's settle step changes after physics (here: particle 1's resting ball given
    0.5 m/s along x) is loaded into that particle's world at the next update, which rolls it about
    5 cm in 0.1 s (before, a world kept what its physics produced); the other particles' balls stay."""
    import dataclasses
    r = 0.03
    scene = table_scene({"id": "ball", "sphere": {"radius": r}, "mass": 0.05, "rolling_friction": 0.002,
                         "pose": {"position": [0.0, 0.0, TABLE_TOP + r]}})
    cfg = EstimatorConfig(particles=4, noise=NoiseConfig.off())
    with SceneEstimator(scene, cfg, np.random.default_rng(0)) as est:
        ball = est.model.M - 1
        settle = est.model.settle
        pushed = []

        def pushing_settle(*args, **kwargs):
            out = settle(*args, **kwargs)
            if not pushed:
                v = out.velocities.copy()
                v[1, ball, :] = [0.5, 0.0, 0.0, 0.0, 0.5 / r, 0.0]
                pushed.append(True)
                return dataclasses.replace(out, velocities=v)
            return out

        for t in (0.0, 0.1, 0.2, 0.3):
            est.update(Frame(t, {}))
            if t == 0.1:
                monkeypatch.setattr(est.model, "settle", pushing_settle)
        x = est.state.poses[:, ball, 0]
    assert x[1] > 0.04, x
    assert np.all(np.abs(x[[0, 2, 3]]) < 1e-3), x


def test_a_ball_rolling_in_view_is_estimated_where_it_is_now_not_an_update_ahead():
    """The belief at t is the scene at t: a ball tracked rolling at 0.9 m/s is within 2 cm of its
    detection at t in every update (teleported to its detection and simulated on, it was 9 cm,
    one 0.1 s update, ahead), and is not taken for held while it rolls freely."""
    scene, frs, _final, _last, _truth = _flicked_ball(x_cut=0.4)
    cfg = EstimatorConfig(particles=16, noise=NoiseConfig(rolling_friction_scale=None))
    with SceneEstimator(scene, cfg, np.random.default_rng(5)) as est:
        beliefs = [(f, est.update(f)) for f in frs]
    rolling = [(f, b) for f, b in beliefs if b is not None and 0.8 <= f.t <= 1.4 and "ball" in f.objects]
    assert len(rolling) >= 5
    for f, b in rolling:
        assert np.linalg.norm(b.objects["ball"].position - f.objects["ball"].position) < 0.02
    assert np.mean([b.objects["ball"].p_held for _, b in rolling]) < 0.5


# ---------------------------------------------------------------------------------------------------
# The five situations of the paper's Fig. 6, on the scenario simulator's streams

from scipy.stats import chi2  # noqa: E402

from estimator.observations import parse_frame  # noqa: E402
from experiments.simulation.simulator import simulate  # noqa: E402


def _estimate(name, seed, k=32):
    res = simulate(name, seed)
    scene = res.scene
    frs = [parse_frame(o, known_ids=scene.object_ids) for o in res.observations]
    with SceneEstimator(scene, EstimatorConfig(particles=k, noise=NoiseConfig()), np.random.default_rng(seed)) as est:
        beliefs = est.run(frs)
    truth = {round(r["t"], 6): r for r in res.truth}
    return beliefs, [truth[round(b.t, 6)] for b in beliefs]


@pytest.mark.parametrize("name, obj, relation, support", [
    ("cup_falls_behind_box", "cup", "isOnTop", "floor"),      # (a) pushed off the table, unseen
    ("ball_dropped_into_box", "ball", "isIn", "box"),         # (b) released, lands out of sight
    ("box_emptied_into_box", "ball", "isIn", "blue_box"),     # (c) poured, never seen
    ("ball_in_moving_box", "ball", "isIn", "box"),            # (d) carried inside a moved box
])
def test_paper_situations_hidden_object_ends_where_it_is(name, obj, relation, support):
    beliefs, truth = _estimate(name, 0)
    end = beliefs[-1]
    assert not end.objects[obj].perceived and not truth[-1]["objects"][obj]["visible"]
    assert end.hypothesis_p(obj, relation, support) > 0.8
    assert {"subject": obj, "predicate": relation, "object": support} in [
        {k: r[k] for k in ("subject", "predicate", "object")} for r in truth[-1]["relations"]]
    if name == "ball_in_moving_box":  # the ball is believed in the box all along, while it moves
        assert all(b.relation_p("ball", "isIn", "box") > 0.8 for b in beliefs)
        start = beliefs[0].objects["ball"].position
        assert max(np.linalg.norm(b.objects["ball"].position - start) for b in beliefs) > 0.2
        err = np.linalg.norm(end.objects["ball"].position - truth[-1]["objects"]["ball"]["position"])
        assert err < 0.15  # inside the same box


def test_paper_situation_e_hidden_while_held_with_tracked_hands():
    """The cup held behind the back is believed held while hidden (the paper's reasoner says it fell),
    over four seeds: in about one run in six, one update near the end of the hidden phase dips
    under 0.5 as the hand comes back, so the claim is on the share of hidden updates (at least 90 %,
    against 0 % for a belief that it fell) and on each run's median."""
    p_held = []
    for seed in range(4):
        beliefs, truth = _estimate("cup_hidden_behind_back", seed)
        run = [b.objects["cup"].p_held for b, tr in zip(beliefs, truth)
               if tr["objects"]["cup"]["held"] and not tr["objects"]["cup"]["visible"] and not b.objects["cup"].perceived]
        assert len(run) >= 10 and np.median(run) > 0.5
        p_held += run
    assert np.mean(np.array(p_held) > 0.5) >= 0.9


def test_paper_mode_fails_situation_e_as_the_paper_reports():
    res = simulate("cup_hidden_behind_back", 0)
    frs = [parse_frame(o, known_ids=res.scene.object_ids) for o in res.observations]
    with SceneEstimator(res.scene, EstimatorConfig.paper()) as est:
        beliefs = est.run(frs)
    hidden = [b for b in beliefs if not b.objects["cup"].perceived]
    assert hidden and hidden[-1].objects["cup"].p_held == 0.0  # released, it falls (Fig. 6e)


def test_calibration_of_a_hidden_objects_90_percent_region():
    n, hits = 20, 0
    for seed in range(n):
        beliefs, truth = _estimate("ball_dropped_into_box", seed, k=16)
        ob = beliefs[-1].objects["ball"]
        assert not ob.perceived
        e = np.asarray(truth[-1]["objects"]["ball"]["position"]) - ob.position
        hits += e @ np.linalg.solve(ob.position_cov, e) <= ob.region(0.9)  # the reported distribution's
    band = 3 * np.sqrt(0.9 * 0.1 / n)
    assert 0.9 - band <= hits / n <= 1.0


@pytest.mark.parametrize("particles", [1, 8])
def test_absurd_detections_are_rejected_outliers_never_beliefs(particles):
    """A position of 1e308 m, or 50 m under the floor, is well-formed JSON but physically absurd:
    it is dropped and counted (outside the scene's workspace), and the belief stays where it was."""
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}))
    at = [0.1, 0.0, TABLE_TOP + 0.03]
    absurd = {0.5: [1e308, 0.0, 0.7], 0.6: [0.1, 0.0, -50.0]}
    frs = [Frame(float(t), {"box": det(absurd.get(round(t, 3), at))}) for t in np.arange(0, 1.5, 0.1)]
    noise = NoiseConfig() if particles > 1 else NoiseConfig.off()
    with SceneEstimator(scene, EstimatorConfig(particles=particles, noise=noise), np.random.default_rng(0)) as est:
        beliefs = est.run(frs)
        assert est.rejected_detections == 2
    for b in beliefs:
        assert np.isfinite(b.objects["box"].position).all()
        assert np.linalg.norm(b.objects["box"].position - at) < 0.05


def test_a_worker_killed_mid_run_is_restarted_and_the_run_goes_on():
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}))
    at = [0.1, 0.0, TABLE_TOP + 0.03]
    frs = frames(np.arange(0, 1.5, 1 / 30), lambda t: {"box": at})
    with SceneEstimator(scene, EstimatorConfig(particles=8, workers=2, worlds=4, noise=NoiseConfig()),
                        np.random.default_rng(0)) as est:
        beliefs = est.run(frs[:15])
        est.pool._procs[0].kill()
        est.pool._procs[0].join()
        beliefs += est.run(frs[15:])
        assert est.pool.restarts == 1 and est.reseeded == 4  # the dead worker's four particles
    for b in beliefs:
        assert np.isfinite(b.objects["box"].position).all() and np.isfinite(b.ess)
    assert np.linalg.norm(beliefs[-1].objects["box"].position - at) < 0.02


def test_a_gap_of_an_hour_simulates_at_most_max_gap():
    """A stream that stops for an hour and resumes: the update after the gap simulates max_gap (2 s)
    of physics, not an hour, and the cup seen in the air (held), let go at the loss in some particles
    (release_on_loss, 0.5 of 8: all kept held has probability 1/256), has fallen onto the table in
    every particle that let it go."""
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}),
                        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}})
    steps = []
    with SceneEstimator(scene, EstimatorConfig(particles=8, noise=NoiseConfig()), np.random.default_rng(0)) as est:
        real_run = est.pool.run

        def counting(batch, n_steps, *a, **kw):
            steps.append(n_steps)
            return real_run(batch, n_steps, *a, **kw)

        est.pool.run = counting
        before = est.run([Frame(t, {"cup": det([-0.2, 0.1, TABLE_TOP + 0.3])}) for t in (0.0, 0.08)])
        after = est.run([Frame(3600.0, {}), Frame(3600.08, {})])
        free = est.state.modes[:, 2] == FREE
        z = est.poses[:, 2, 2]
    assert steps == [0, 19, 480, 19]
    assert before[-1].objects["cup"].perceived and not after[-1].objects["cup"].perceived
    assert np.any(free) and np.all((TABLE_TOP < z[free]) & (z[free] < TABLE_TOP + 0.05))  # standing or lying


# -- held objects out of view (the hand's motion and visibility) -------------------------------------
CUP_SPEC = {"id": "cup", "cylinder": {"radius": 0.035, "height": 0.1}, "mass": 0.15,
            "pose": {"position": [0.0, -0.3, TABLE_TOP + 0.05]}}


def _carry_frames(hand_path, t_end, cup_until, dt=1 / 30):
    """Frames every ``dt`` s to ``t_end``: the hand at ``hand_path(t)``, the cup 8 cm under it and
    detected until ``cup_until`` s (from t = 0.3 s: before, it rests where the scene has it)."""
    out = []
    for t in np.arange(0.0, t_end, dt):
        hand = np.asarray(hand_path(t), float)
        objs = {}
        if t < 0.3:
            objs["cup"] = Detection(np.array([0.0, -0.3, TABLE_TOP + 0.05]))
        elif t < cup_until:
            objs["cup"] = Detection(hand - [0.0, 0.0, 0.08])
        out.append(Frame(float(t), objs, {"human/right": hand}))
    return out


def test_a_carried_object_stays_held_while_its_tracked_hand_keeps_moving_out_of_view():
    """No camera: the cup is lifted and carried, then no longer reported while the hand goes on
    moving for 2.7 s. It stays held (P > 0.8 at every step; the prior release_on_loss_carried is
    0.024 and a moving hand does not let go later) and its position follows the hand."""
    scene = table_scene(CUP_SPEC)

    def hand(t):
        s = max(0.0, t - 0.3)
        return [0.0 + 0.25 * np.sin(1.5 * s), -0.3 + 0.2 * s, TABLE_TOP + 0.13 + min(s, 0.2)]

    frames = _carry_frames(hand, 4.0, cup_until=1.3)
    with SceneEstimator(scene, EstimatorConfig(particles=32, noise=NoiseConfig()), np.random.default_rng(5)) as est:
        beliefs = est.run(frames)
    after = [b for b in beliefs if 1.3 <= b.t]
    assert after[-1].t - after[0].t > 2.5
    assert all(b.objects["cup"].p_held > 0.8 for b in after), [round(b.objects["cup"].p_held, 2) for b in after]
    last = after[-1].objects["cup"]
    expect = np.asarray(hand(after[-1].t)) - [0.0, 0.0, 0.08]
    assert np.linalg.norm(last.position - expect) < 0.06


def test_a_still_visible_hand_whose_object_vanishes_has_let_it_go():
    """The hand carries the cup beyond the table's far edge and stays still in the camera's view; the
    cup is no longer reported (it fell behind the table, where the camera cannot see the floor).
    Particles that keep it in the still hand would show it; within 1.5 s of the loss P(held) is
    below 0.2 (prior 0.5 at the loss, then miss_prob = 0.1 against at every update: a hand that has
    not moved since the cup was seen cannot hide it but with itself) and the cup is on the floor."""
    camera = {"position": [1.1, 0.0, 1.15], "target": [-0.3, 0.0, 0.7], "fov_deg": 60}
    scene = table_scene(CUP_SPEC, camera=camera)

    def hand(t):
        s = min(max(0.0, t - 0.3) / 0.8, 1.0)
        return [-0.88 * s, -0.3 * (1 - s), TABLE_TOP + 0.15 + 0.1 * s]

    frames = _carry_frames(hand, 4.0, cup_until=1.4)
    with SceneEstimator(scene, EstimatorConfig(particles=64, noise=NoiseConfig()), np.random.default_rng(2)) as est:
        beliefs = est.run(frames)
    loss = 1.4 + EstimatorConfig().reasoner.t_perceived
    late = [b for b in beliefs if b.t >= loss + 1.5]
    assert late, "the stream must run past the loss"
    assert all(b.objects["cup"].p_held < 0.2 for b in late), [round(b.objects["cup"].p_held, 2) for b in late]
    assert late[-1].objects["cup"].position[2] < 0.15  # on the floor


def test_a_hand_back_in_view_without_its_object_let_it_go_where_it_was_hidden():
    """The hand carries the cup behind a screen (the cup stops being reported there), puts it down,
    and comes back into the camera's view without it. The particles that kept it in the hand would
    show it there; those that let it go where the screen hid it (release_behind_cover, prior
    release_hidden = 0.226) explain the view: P(held) ends below 0.3 (about 0.25 expected: the held
    ones lose at most the factor hand_occlusion) and the cup is on the table behind the screen, put
    down: the timeline has a Place (put_down_hidden: let go where it was lowest, at the 2.4 s the hand
    lowered it) and no Release. Without the moves (release_hidden = 0, put_down_touched = 0) the few
    particles that let it go at the loss fall in view, and the cup stays held."""
    from dataclasses import replace

    from actions.modes import ModePriors

    camera = {"position": [1.1, 0.0, 1.15], "target": [-0.3, 0.0, 0.7], "fov_deg": 60}
    screen = {"id": "screen", "static": True, "box": {"size": [0.08, 0.5, 0.38]},
              "pose": {"position": [-0.15, 0.0, TABLE_TOP + 0.19]}}
    scene = table_scene(screen, CUP_SPEC, camera=camera)
    way = [(0.3, [0.0, -0.3, TABLE_TOP + 0.13]), (0.8, [0.0, -0.3, TABLE_TOP + 0.2]),
           (1.5, [-0.42, -0.45, TABLE_TOP + 0.2]), (2.1, [-0.42, 0.0, TABLE_TOP + 0.2]),
           (2.4, [-0.42, 0.0, TABLE_TOP + 0.13]), (2.7, [-0.42, 0.0, TABLE_TOP + 0.3]), (3.5, [0.3, 0.35, 1.0])]

    def hand(t):
        times = [w[0] for w in way]
        pts = np.array([w[1] for w in way])
        return [np.interp(t, times, pts[:, i]) for i in range(3)]

    frames = _carry_frames(hand, 5.0, cup_until=1.7)
    put_down = np.array([-0.42, 0.0])
    cfg = EstimatorConfig(particles=64, noise=NoiseConfig())
    with SceneEstimator(scene, cfg, np.random.default_rng(4)) as est:
        last = est.run(frames)[-1].objects["cup"]
        events = [(e["action"], e["t"]) for e in est.timeline.to_json()["events"] if e["subject"] == "cup"]
    assert last.p_held < 0.3
    lets = [(a, t) for a, t in events if a in ("Place", "Release")]
    assert len(lets) == 1 and lets[0][0] == "Place" and abs(lets[0][1] - 2.4) < 0.25, events
    assert last.hypotheses[0].support == "table" and last.hypotheses[0].p > 0.5
    assert np.linalg.norm(last.position[:2] - put_down) < 0.2
    cfg0 = replace(cfg, priors=replace(ModePriors(), release_hidden=0.0, put_down_touched=0.0))
    with SceneEstimator(scene, cfg0, np.random.default_rng(4)) as est:
        assert est.run(frames)[-1].objects["cup"].p_held > 0.5
    # set down out of view: where the cup rested on the table at its lowest, the hand lifting away
    # lets it go in most particles (put_down_touched) before the hand shows in view without it
    for p, check in ((ModePriors().put_down_touched, lambda h: h < 0.5), (0.0, lambda h: h > 0.9)):
        cfg1 = replace(cfg, priors=replace(ModePriors(), put_down_touched=p))
        with SceneEstimator(scene, cfg1, np.random.default_rng(4)) as est:
            held = [b.objects["cup"].p_held for b in est.run(frames) if 2.6 <= b.t <= 3.0]
        assert held and all(check(h) for h in held), (p, held)


def test_a_resting_object_converges_to_the_mean_of_its_detections():
    """A box at rest, seen at 30 Hz with 3 mm noise for 2 s by an estimator that assumes 1 cm, end
    to end: the horizontal estimate is within 3 standard errors of the truth for an average of the
    detections (about 20 updates: 3 mm / sqrt(20) = 0.7 mm per axis, plus the cloud's Monte-Carlo
    error, 1 cm / sqrt(20) / sqrt(32) = 0.4 mm), and the cloud's spread is a posterior's, not the
    1 cm it was drawn with. (On this clean scene weighting alone comes close too; the Kalman step
    itself is tested on the model, test_rest_fusion.py, and in test_fusion.py.)"""
    from estimator.config import NoiseConfig

    at = np.array([0.1, 0.0, TABLE_TOP + 0.03])
    rng = np.random.default_rng(11)
    frs = frames(times(2.0), lambda t: {"box": list(at + [0, 0, 0.01] + rng.normal(0, 0.003, 3))})
    se = np.hypot(0.003 / np.sqrt(20), 0.01 / np.sqrt(20 * 32))
    cfg = EstimatorConfig(particles=32, noise=NoiseConfig())
    with SceneEstimator(table_scene(dict(BOX, pose={"position": at.tolist()})), cfg, np.random.default_rng(2)) as est:
        end = est.run(frs)[-1].objects["box"]
        spread = np.sqrt(np.cov(est.poses[:, 1, :2].T, aweights=est.last_belief.weights).diagonal())
    assert np.all(np.abs(end.position[:2] - at[:2]) < 3 * se)  # 2.4 mm
    # the cloud's spread is the Kalman posterior's of 20 detections assumed 1 cm (2.2 mm), not the
    # 1 cm it was drawn with
    assert np.all(spread < 0.005)


def test_the_kalman_step_keeps_a_resting_stack_asleep_and_in_place():
    """Three boxes stacked on the table, seen at 30 Hz with 3 mm noise for 3 s: the horizontal
    Kalman steps of the resting boxes load them asleep (they, and what they carry, are not woken
    and settled again at every step of the fusion), so the stack sleeps about as much as with no
    fusion at all; and it stays a stack, each box within a few millimetres of where it rests."""
    from estimator.config import NoiseConfig

    size = 0.06
    at = {f"b{i}": np.array([0.1, 0.0, TABLE_TOP + size * (i + 0.5)]) for i in range(3)}
    rng = np.random.default_rng(5)
    frs = frames(times(3.0), lambda t: {o: list(p + rng.normal(0, 0.003, 3)) for o, p in at.items()})
    scene = table_scene(*[dict(BOX, id=o, pose={"position": p.tolist()}) for o, p in at.items()])
    awake, ends = {}, {}
    for fuse in (True, False):
        cfg = EstimatorConfig(particles=32, noise=NoiseConfig(fuse_resting=fuse))
        with SceneEstimator(scene, cfg, np.random.default_rng(2)) as est:
            n = []
            for fr in frs:
                if est.update(fr) is not None:
                    n.append(np.any(est.state.velocities[:, 1:] != 0.0, axis=-1).mean())
            awake[fuse], ends[fuse] = np.mean(n[len(n) // 2:]), est.last_belief.objects
    # the entries awake over the second half of the run (with 32 particles x 3 boxes, a difference
    # of a few entries per update is noise)
    assert awake[True] < awake[False] + 0.1
    for o, p in at.items():
        est_p = np.asarray(ends[True][o].position)
        assert np.linalg.norm(est_p[:2] - p[:2]) < 0.004 and abs(est_p[2] - p[2]) < 0.004


def test_frames_observed_during_a_long_update_are_merged_into_one_step():
    """A live stream that fell behind: frames observed without a step (``observe``) still feed the
    perception memory, and the next ``step`` simulates the whole elapsed time in one update."""
    scene = table_scene(dict(BOX, pose={"position": [0.1, 0, TABLE_TOP + 0.03]}))
    steps = []
    frs = [Frame(float(t), {"box": det([0.1, 0.0, TABLE_TOP + 0.03])}) for t in times(1.0)]
    with SceneEstimator(scene, EstimatorConfig.paper()) as est:
        real_run = est.pool.run

        def counting(batch, n_steps, *a, **kw):
            steps.append(n_steps)
            return real_run(batch, n_steps, *a, **kw)

        est.pool.run = counting
        with pytest.raises(ValueError):
            est.step()  # nothing observed yet
        est.update(frs[0])
        for f in frs[1:10]:  # 0.3 s of frames arrive while an update runs
            est.observe(f)
        belief = est.step()
        with pytest.raises(ValueError):
            est.step()  # no new frame since
        assert belief.t == frs[9].t and belief.objects["box"].perceived
    assert steps == [0, int(round(frs[9].t * 240))]


@pytest.mark.parametrize("clip", [True, False])
def test_a_carried_object_never_ends_inside_the_table(clip):
    """The cup is lifted and carried by a tracked hand, then no longer reported (no camera: nothing
    says where it is but the hand) while the hand goes down through the table top to 30 cm under
    it (a skeleton tracker's hand can be anywhere). A held object's path stops at the surface of
    static geometry: at every update no particle has the cup more than 1 cm inside the table or the
    floor, and it ends on the table top. Without the clip (``static_clip`` off) the hand takes it
    through the table: the test sees it."""
    from physics.penetration import INVARIANT_DEPTH, StaticGeometry

    scene = table_scene(CUP_SPEC)

    def hand(t):
        up = min(max(0.0, t - 0.3) / 0.5, 1.0)  # lifted 20 cm, then from 33 cm above the top to 30 cm under it
        down = min(max(0.0, t - 1.3) / 1.2, 1.0)
        return [0.0, -0.3, TABLE_TOP + 0.13 + 0.2 * up - 0.63 * down]

    frames = _carry_frames(hand, 3.2, cup_until=1.2)
    config = replace(EstimatorConfig(particles=16, noise=NoiseConfig()), static_clip=clip)
    deepest = 0.0
    with StaticGeometry(scene) as geometry, SceneEstimator(scene, config, np.random.default_rng(3)) as est:
        for f in frames:
            if est.update(f) is not None:
                deepest = max(deepest, float(geometry.depths(est.poses, est.known).max()))
        z = est.poses[:, 1, 2]
    if clip:
        assert deepest <= INVARIANT_DEPTH
        assert np.all(np.abs(z - (TABLE_TOP + 0.05)) < 0.01)  # on the table top (the cup's half height 5 cm)
    else:
        assert deepest > INVARIANT_DEPTH


def test_a_ball_let_go_from_a_still_visible_hand_is_not_held_a_second_after_it_vanished():
    """The hand carries a ball over an open bin, stops there in the camera's view, and lets go; the
    ball drops into the bin and is never reported again. A hand that has not moved since its
    object was last seen can hide it only with itself (a 4.5 cm sphere, well above the ball here):
    the particles that keep it in the hand put it in plain view and pay miss_prob per update, with
    no allowance for the person hiding it (that is for carried objects). Within 1 s of its last
    detection P(held) is below 0.2 (0.5 at the loss, then about 0.09 after one update) and the ball
    is in the bin."""
    camera = {"position": [1.1, 0.0, 1.25], "target": [-0.2, 0.0, 0.7], "fov_deg": 60}
    ball = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05,
            "pose": {"position": [0.25, -0.2, TABLE_TOP + 0.03]}}
    bin_ = {"id": "bin", "container": {"size": [0.22, 0.22, 0.16], "wall": 0.01}, "mass": 0.6,
            "pose": {"position": [-0.2, 0.15, TABLE_TOP + 0.08]}}
    scene = table_scene(bin_, ball, camera=camera)
    over = np.array([-0.2, 0.15, TABLE_TOP + 0.16 + 0.12])

    def hand(t):
        s = min(max(0.0, t - 0.3) / 0.8, 1.0)
        start = np.array([0.25, -0.2, TABLE_TOP + 0.09])
        return start + (over - start) * (3 * s * s - 2 * s ** 3)

    last = 1.5  # the hand has been still over the bin since 1.1 s
    out = []
    for t in np.arange(0.0, 3.0, 1 / 30):
        h = hand(t)
        objs = {"bin": det(bin_["pose"]["position"])}
        if t < 0.3:
            objs["ball"] = det(ball["pose"]["position"], None)
        elif t <= last:
            objs["ball"] = det(h - [0.0, 0.0, 0.06], None)
        out.append(Frame(float(t), objs, {"human/right": h}))
    with SceneEstimator(scene, EstimatorConfig(particles=64, noise=NoiseConfig()), np.random.default_rng(4)) as est:
        beliefs = est.run(out)
    later = [b for b in beliefs if b.t >= last + 1.0]
    assert later and all(b.objects["ball"].p_held < 0.2 for b in later), \
        [(round(b.t, 2), round(b.objects["ball"].p_held, 2)) for b in beliefs if b.t > last]
    end = later[-1]
    assert end.relation_p("ball", "isIn", "bin") > 0.8


def test_a_box_pushed_out_of_view_stays_on_the_table_when_the_hand_rises_off_it():
    """A tracked hand slides a box 40 cm along the table (never lifting it) and on out of the
    detector's reach (the box is no longer reported from 1.4 s, while it still moves: no camera, so nothing says where it
    is but the hand), then rises 30 cm and goes away. A push cannot lift: once the hand is above
    the box, every particle leaves it where the push took it, on the table, and the episode ends as
    a Push. (Read as carried, 98 % of the particles kept it in the rising hand: the carry prior.)"""
    box = {"id": "box", "box": {"size": [0.08, 0.08, 0.08]}, "mass": 0.3,
           "pose": {"position": [0.2, 0.0, TABLE_TOP + 0.04]}}
    scene = table_scene(box)
    z = TABLE_TOP + 0.04

    def box_at(t):
        s = min(max(0.0, t - 0.5) / 1.8, 1.0)
        return np.array([0.2 - 0.4 * (3 * s * s - 2 * s ** 3), 0.0, z])

    def hand(t):
        up = min(max(0.0, t - 2.5) / 0.6, 1.0)
        return box_at(t) + [0.08, 0.0, 0.3 * up]

    out = []
    for t in np.arange(0.0, 3.8, 1 / 30):
        objs = {"box": det(box_at(t))} if t < 1.4 else {}
        out.append(Frame(float(t), objs, {"human/right": hand(t)}))
    with SceneEstimator(scene, EstimatorConfig(particles=32, noise=NoiseConfig()), np.random.default_rng(6)) as est:
        beliefs = est.run(out)
        timeline = est.timeline.to_json()
    end = beliefs[-1].objects["box"]
    assert end.p_held < 0.1
    assert end.hypotheses[0].support == "table" and abs(end.position[2] - z) < 0.01
    assert np.linalg.norm(end.position[:2] - box_at(3.8)[:2]) < 0.08
    assert [e["action"] for e in timeline["events"]] == ["Push"], timeline["events"]


def _rolled_ball(scale, seed=0):
    """A ball flicked along the table in a pybullet world whose rolling friction is ``scale`` times
    the one the estimator's scene states; detections every 1/30 s with 3 mm of noise. Returns the
    estimator's scene, the frames and the nominal rolling friction."""
    from physics.world import World

    nominal = 0.002
    ball = {"id": "ball", "sphere": {"radius": 0.03}, "mass": 0.05, "rolling_friction": nominal,
            "pose": {"position": [0.4, 0.0, TABLE_TOP + 0.03]}}
    rng = np.random.default_rng(seed)
    out = []
    with World(table_scene(dict(ball, rolling_friction=nominal * scale))) as w:
        b = w.index("ball")
        for i in range(int(2.5 * 240)):
            if i == int(0.3 * 240):  # flicked: 1 m/s, rolling
                v = np.array([-1.0, 0.05, 0.0, 0.0, 0.0, 0.0])
                v[3:] = np.cross([0.0, 0.0, 1.0], v[:3]) / 0.03
                w.set_velocities(v[None], [b])
            w.step(1)
            if i % 8 == 0:
                p = w.get_poses([b])[0, :3]
                out.append(Frame(i / 240, {"ball": Detection(p + rng.normal(0.0, 0.003, 3), None)}))
    return table_scene(ball), out, nominal


@pytest.mark.parametrize("scale", [3.0, 0.4])
def test_a_rolling_balls_friction_posterior_follows_its_motion_beyond_the_prior(scale):
    """The scene file states a rolling friction three times too low (or 2.5 times too high); the
    prior spreads it only by a factor of two (log-uniform over half to twice the stated value:
    mean 1.08, standard deviation 0.43 times it). The ball is seen rolling for two seconds: how
    fast it slows down is evidence (the velocity term), and the parameters keep enough spread to
    follow it. The posterior mean reported in the estimate stream moves off the prior's mean
    towards the truth by more than three standard errors of a mean of K draws from the prior
    (what sampling alone would give with probability 0.13 %)."""
    from estimator.config import default_config

    cfg = replace(default_config(64), workers=0)
    lo, hi = cfg.noise.rolling_friction_scale
    prior_mean = (hi - lo) / math.log(hi / lo)
    prior_std = math.sqrt((hi * hi - lo * lo) / (2.0 * math.log(hi / lo)) - prior_mean ** 2)
    band = 3.0 * prior_std / math.sqrt(cfg.particles)
    scene, frs, nominal = _rolled_ball(scale)
    with SceneEstimator(scene, cfg, np.random.default_rng(1)) as est:
        beliefs = est.run(frs)
    mean, std = beliefs[-1].objects["ball"].parameters["rolling_friction"]
    assert std > 0
    if scale > 1:
        assert mean / nominal > prior_mean + band
    else:
        assert mean / nominal < prior_mean - band


# -- the adaptive particle count (AdaptiveConfig) ------------------------------------------------------
from estimator.config import AdaptiveConfig, with_budget  # noqa: E402
from estimator.resampling import normalise_log_weights  # noqa: E402


def _adaptive(max_particles=512, workers=0):
    return EstimatorConfig(particles=64, workers=workers, noise=NoiseConfig(),
                           adaptive=AdaptiveConfig(enabled=True, min_particles=16, max_particles=max_particles))


def test_the_adaptive_count_falls_to_its_minimum_on_a_resting_scene_and_grows_when_a_ball_rolls_out_of_view():
    boxes = [dict(BOX, id=f"b{i}", pose={"position": [0.2 * i - 0.2, 0.1, TABLE_TOP + 0.03]}) for i in range(3)]
    frs = frames(times(1.5), lambda t: {f"b{i}": [0.2 * i - 0.2, 0.1, TABLE_TOP + 0.03] for i in range(3)})
    with SceneEstimator(table_scene(*boxes), _adaptive(), np.random.default_rng(4)) as est:
        ks = [b.n_particles for b in est.run(frs)]
        assert ks[0] == 64 and all(k == 16 for k in ks[4:])  # within a few updates, and it stays there
        assert est.pool.shard_sizes == [16]
        line = est.last_belief.to_json()
        assert line["particles"] == 16
    scene, frs, _final, (t_last, _p), _truth = _flicked_ball()
    with SceneEstimator(scene, _adaptive(), np.random.default_rng(4)) as est:
        out = [(b.t, b.n_particles) for b in est.run(frs)]
    at_rest = [k for t, k in out if 0.1 < t < 0.5]
    gone = [k for t, k in out if t > t_last + 1.0]
    assert at_rest and max(at_rest) == 16
    # out of view, its rolling friction unknown within a factor of four: it could be anywhere along
    # tens of centimetres, many 5 cm bins: the count grows far beyond where it started
    assert min(gone) > 200 and max(gone) <= 512


def test_the_adaptive_count_gives_the_same_output_whatever_the_number_of_workers():
    scene, frs, *_ = _flicked_ball()
    outs = []
    for workers in (0, 1, 2):
        with SceneEstimator(scene, _adaptive(160, workers), np.random.default_rng(9)) as est:
            outs.append(([json.dumps(b.to_json()) for b in est.run(frs)], est.timeline.to_json()))
    assert outs[0] == outs[1] == outs[2]
    ks = {json.loads(line)["particles"] for line in outs[0][0]}
    assert min(ks) == 16 and max(ks) == 160  # it shrank and grew in the run compared


def test_a_growing_count_splits_the_particles_instead_of_resampling_them():
    """Each time the count grows (the ball rolled out of view), the particles before stay in their
    slots as they were (poses, velocities, parameters, bit for bit), each one's weight shared with
    its copies (an integer number of them, n in all): the weighted belief is the one the weights
    gave. Once the ball is out of sight its copies are jittered: none sits where a particle does
    (while it is seen, the detections place it, as after a resampling)."""
    scene, frs, *_ = _flicked_ball()
    ball, grown = scene.object_ids.index("ball"), 0
    with SceneEstimator(scene, _adaptive(), np.random.default_rng(4)) as est:
        for f in frs:
            est.observe(f)
            if not reasoning_due(est.t_tick, f.t, est.config.reasoner.horizon):
                continue
            seen = est.step(defer=True).objects["ball"].perceived
            if est._pending is None or est._pending[0].__name__ != "_grow":
                est.finish()
                continue
            grown += not seen
            before = est.state
            w, _ = normalise_log_weights(before.log_weights)
            K = len(w)
            est.finish()
            after = est.state
            n = len(after.log_weights)
            assert n > K and est.K == n
            for name in ("poses", "velocities", "params", "modes"):
                assert np.array_equal(getattr(after, name)[:K], getattr(before, name)[:K])
            w2, _ = normalise_log_weights(after.log_weights)
            live = w > 0
            copies = w[live] / w2[:K][live]
            assert np.allclose(copies, np.round(copies), rtol=1e-9) and np.all(np.round(copies) >= 1)
            assert round(copies.sum()) + np.count_nonzero(~live) == n  # no copy of a weightless particle
            old = {tuple(p) for p in before.poses[:, ball, :3]}
            assert seen or not any(tuple(p) in old for p in after.poses[K:, ball, :3])
    assert grown >= 2


def _timed_by_k(est, cost):
    """Make ``est``'s budget clock read that a step costs ``cost(t)`` s per particle, t the frame's
    time (s): a machine of known speed, so that the count it affords is known."""
    now = [0.0]
    advance = est.pool.advance

    def timed(batch, *args, **kwargs):
        now[0] += cost(est.t_frame) * len(batch.poses)
        return advance(batch, *args, **kwargs)

    est.clock = lambda: now[0]
    est.pool.advance = timed


def test_a_budget_sheds_particles_while_the_steps_cannot_keep_up_and_takes_them_back_when_they_can():
    """Steps every 0.1 s of stream time (30 Hz, horizon 0.08 s); a particle costs 0.08 / 20.5 s per
    step for the first 1.5 s (20 particles load the machine 78 %, under the 80 % allowed), ten times
    less after. The count falls from 64 to 20 at the first budgeted step and stays there; then it
    grows by 1.25 per step back to 64, never beyond. The worlds it keeps are spread over both
    workers."""
    boxes = [dict(BOX, id=f"b{i}", pose={"position": [0.2 * i - 0.2, 0.1, TABLE_TOP + 0.03]}) for i in range(3)]
    frs = frames(times(3.0), lambda t: {f"b{i}": [0.2 * i - 0.2, 0.1, TABLE_TOP + 0.03] for i in range(3)})
    cfg = with_budget(EstimatorConfig(particles=64, workers=2, noise=NoiseConfig()), min_particles=8)
    with SceneEstimator(table_scene(*boxes), cfg, np.random.default_rng(4)) as est:
        _timed_by_k(est, lambda t: 0.08 / 20.5 if t < 1.5 else 0.008 / 20.5)
        out = [(b.t, b.n_particles) for b in est.run(frs[:45])]
        assert est.pool.shard_sizes == [12, 8]  # one slot per client in turn (8 clients), not slots 0-19
        out += [(b.t, b.n_particles) for b in est.run(frs[45:])]
    slow = [k for t, k in out if t < 1.5]
    fast = [k for t, k in out if t >= 1.5]
    assert slow[:2] == [64, 64] and set(slow[2:]) == {20}  # the first update simulates nothing: not timed
    assert fast[:7] == [20, 25, 32, 40, 50, 63, 64] and set(fast[7:]) == {64}
    assert max(k for _, k in out) == 64 and est.k_range[:2] == [20, 64]
    # with an adaptive count, the budget caps what KLD-sampling asks for (a ball rolled out of view
    # asks for hundreds, as the test above shows): the first step over 40 particles sets the cap,
    # and from there no step runs more than 40
    scene, frs, *_ = _flicked_ball()
    cfg = with_budget(_adaptive(), min_particles=8)
    with SceneEstimator(scene, cfg, np.random.default_rng(4)) as est:
        _timed_by_k(est, lambda t: 0.08 / 40.5)
        ks = [b.n_particles for b in est.run(frs)]
    over = [i for i, k in enumerate(ks) if k > 40]
    assert ks[:2] == [64, 16] and len(over) == 2, ks  # the first update (not timed) and one more
    assert max(ks[over[1] + 1:]) == 40 and ks[-10:] == [40] * 10, ks


def _filter_entries(est, frame):
    """The functions of estimator/filter.py entered while ``est`` processes ``frame``, in order."""
    import sys

    import estimator.filter as module
    entered = []

    def profile(f, event, arg):
        if event == "call" and f.f_code.co_filename == module.__file__:
            entered.append(f.f_code.co_name)

    sys.setprofile(profile)
    try:
        est.update(frame)
    finally:
        sys.setprofile(None)
    return entered


def test_a_frame_enters_the_filter_at_most_four_times_through_an_update_that_resamples():
    """The loop is the filter's, the decisions the model's: one update that steps and resamples enters
    filter.py in update, observe, step and the resampling, nothing more."""
    box = {"id": "box", "box": {"size": [0.06, 0.06, 0.06]}, "pose": {"position": [0, 0, TABLE_TOP + 0.03]}}
    cfg = EstimatorConfig(particles=8, workers=0, noise=NoiseConfig(), resample_threshold=1.0)  # resample
    with SceneEstimator(table_scene(box), cfg, np.random.default_rng(0)) as est:
        # first seen 10 cm from where the scene has it: placed at its detection, height noise included,
        # which the next update weighs (seen where the scene has it, each particle keeps its height)
        est.update(Frame(0.0, {"box": det([0.1, 0.0, TABLE_TOP + 0.03])}))
        entered = _filter_entries(est, Frame(0.1, {"box": det([0.11, 0.0, TABLE_TOP + 0.03])}))
    assert entered[:3] == ["update", "observe", "step"] and "_resample" in entered
    assert len(entered) <= 4, entered


@pytest.mark.parametrize("particles", [1, 16])
def test_a_hand_rising_beside_a_still_box_it_never_held_does_not_carry_it(particles):
    """A hand that has just put something beside a box rises at 1 m/s while the box, at rest on the
    table and seen still, is missed for two frames of an update: no particle holds it, nothing
    moved it, so its detection stays where it was seen. Carried up with the hand (6.7 cm over the
    two frames, past the 4.5 cm divergence threshold), it was lifted 7 cm off the table in every
    particle and overridden there (paper mode follows no hands)."""
    scene = table_scene(BOX)
    rest = np.array([0.0, 0.0, TABLE_TOP + 0.03])

    def hand(t):
        return rest + [0.08, 0.0, 0.12 + max(0.0, t - 1.0)]  # still, then rising from t = 1 s

    out = []
    for t in times(2.0):
        missed = 1.05 < t < 1.1 + 0.5 / HZ  # the update's last two frames (1.067 and 1.1 s)
        out.append(Frame(float(t), {} if missed else {"box": det(rest)}, {"human/right": hand(t)}))
    config = EstimatorConfig.paper() if particles == 1 else EstimatorConfig(particles=particles)
    with SceneEstimator(scene, config, np.random.default_rng(3)) as est:
        beliefs = est.run(out)
        events = est.timeline.to_json()["events"]
    heights = [b.objects["box"].position[2] for b in beliefs]
    assert np.max(np.abs(np.array(heights) - rest[2])) < 0.01, np.round(heights, 3)
    assert all(b.objects["box"].p_plausible > 0.99 for b in beliefs)
    assert not any(e["subject"] == "box" for e in events), events
