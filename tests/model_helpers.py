"""A small scene for the scene model's tests (no worlds): a table, a crate, a ball in it, a cup and
an object without a pose; and a model of it under a configuration."""
import dataclasses
import math

import numpy as np

from actions.modes import HELD
from estimator.model import SceneModel, initial_poses
from estimator.model.perception_memory import PerceptionMemory
from estimator.observations import Detection, Frame
from estimator.worlds.pool import BatchOutput
from physics.scene import scene_from_dict

TABLE, CRATE, BALL, CUP, MYSTERY = range(5)
YAW90 = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])


def scene():
    return scene_from_dict({"objects": [
        {"id": "table", "static": True, "box": {"size": [1.0, 1.0, 0.1]}, "pose": {"position": [0, 0, 0.05]}},
        {"id": "crate", "container": {"size": [0.3, 0.2, 0.12], "wall": 0.01}, "pose": {"position": [0, 0, 0.16]}},
        {"id": "ball", "sphere": {"radius": 0.03}, "pose": {"position": [0.08, 0.0, 0.14]}},
        {"id": "cup", "cylinder": {"radius": 0.03, "height": 0.08}, "pose": {"position": [0.3, 0.3, 0.14]}},
        {"id": "mystery", "sphere": {"radius": 0.02}}]})  # no pose: unknown until perceived


def make(config):
    """A :class:`SceneModel` of :func:`scene` under ``config``, its memory built as the tests need it;
    its particles start at the scene's poses exactly (``rest_prior`` off: tests/test_prior.py tests
    the prior at rest)."""
    config = dataclasses.replace(config, rest_prior=False)
    sc = scene()
    memory = PerceptionMemory(sc, initial_poses(sc)[0], config.reasoner, config.follow_hands)
    base = np.tile([0.5, 0.0, 0.0, 0.1, 0.2], (len(sc.objects), 1))
    return SceneModel(sc, config, base, memory)


def cup_held_seen_still(model, st, z, cup_boxes):
    """The cup seen still at height ``z`` (m) for 0.4 s, and the update's move; for
    :func:`estimator.model.settle.settle`, the cup HELD in both particles, whose physics put it in the boxes
    ``cup_boxes (2, 2, 3)`` (the table, crate and ball where ``scene()`` has them):
    ``(t, perceived, move, modes, out)``."""
    for i in range(13):  # 0.4 s still
        model.memory.record(Frame(i / 30, {"cup": Detection(np.array([0.3, 0.3, z]))}))
    t = 12 / 30
    perceived = model.memory.perceived(t)
    mv = model.move(st, Frame(t), perceived, perceived, 0.0, np.random.default_rng(0))
    modes = np.zeros((2, 5), np.int8)
    modes[:, CUP] = HELD
    aabbs = np.zeros((2, 5, 2, 3))
    aabbs[:, TABLE] = [[-0.5, -0.5, 0.0], [0.5, 0.5, 0.1]]
    aabbs[:, CRATE] = [[-0.15, -0.1, 0.1], [0.15, 0.1, 0.22]]
    aabbs[:, BALL] = [[0.05, -0.03, 0.11], [0.11, 0.03, 0.17]]
    aabbs[:, CUP] = cup_boxes
    out = BatchOutput(st.poses.copy(), st.velocities.copy(), modes, np.zeros((2, 5)), aabbs, np.ones(2, bool),
                      np.zeros((2, 5)))
    return t, perceived, mv, modes, out
