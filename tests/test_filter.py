"""The estimator in paper mode (one world, no noise): the behaviours of the IROS 2019 reasoner."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimator.config import EstimatorConfig
from estimator.filter import SceneEstimator
from estimator.observations import Frame

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
    assert np.allclose(ball.position[:2], [0.2, 0.1 + 0.08], atol=0.03)  # offset rotated by 90 deg
    assert beliefs[-1].relation_p("ball", "isIn", "crate") == 1.0


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
