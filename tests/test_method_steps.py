"""The step estimates of experiments.evaluation.method_steps: the support read from relations and
the last-seen baseline."""
from __future__ import annotations

import numpy as np
from test_methods import BALL, CUP, _cup_vanishes

from experiments.evaluation.method_steps import LastSeenBaseline, top_from_relations
from helpers import TABLE_TOP, frames, table_scene


def test_top_from_relations_priority():
    rels = {("ball", "isOnTop", "table"): 1.0, ("ball", "isIn", "box"): 0.7, ("cup", "isIn", "box"): 0.3}
    assert top_from_relations(rels, "ball") == ("isIn", "box")
    assert top_from_relations(rels, "cup") == ("none", None)
    assert top_from_relations(rels, "cup", held=True) == ("held", None)


def test_last_seen_keeps_an_unperceived_object_where_it_was_last_seen():
    scene = table_scene(CUP, BALL)
    frs = frames(np.arange(1, 60) / 30.0, _cup_vanishes)
    with LastSeenBaseline(scene) as base:
        steps = [s for s in (base.update(f) for f in frs) if s is not None]
    cup = scene.index("cup")
    late = [s for s in steps if s.t > 1.0]
    assert late
    for s in late:
        np.testing.assert_allclose(s.positions[cup], [0.1, 0.3, TABLE_TOP + 0.05])
        assert np.all(s.covariances == 0) and np.all(s.p_plausible == 1) and np.all(s.p_held == 0)
        assert s.top[cup] == ("isOnTop", "table")
        assert s.relations[("cup", "isOnTop", "table")] == 1.0
