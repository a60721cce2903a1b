"""No impossible state, ever: on every built-in scenario, after every update, no object of any particle
is more than 1 cm inside static geometry (the table, the floor) (physics.penetration), whichever engine
simulated the truth."""
from dataclasses import replace

import numpy as np
import pytest

from estimator.config import default_config
from estimator.filter import SceneEstimator
from estimator.observations import parse_frame
from experiments.scenarios import list_scenarios
from experiments.simulation.simulator import simulate
from physics.penetration import INVARIANT_DEPTH, StaticGeometry

K = 8
ENGINES = ["bullet", "mujoco"]


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", list_scenarios())
def test_no_particle_is_ever_inside_static_geometry(name, engine):
    sim = simulate(name, 0, engine=engine)
    scene = sim.scene
    worst = (0.0, None)
    with StaticGeometry(scene) as geometry, \
            SceneEstimator(scene, replace(default_config(K), workers=0), np.random.default_rng(0)) as est:
        for f in sim.observations:
            b = est.update(parse_frame(f, known_ids=scene.object_ids))
            if b is None:
                continue
            d = geometry.depths(est.poses, est.known)
            if d.max() > worst[0]:
                k, m = np.unravel_index(np.argmax(d), d.shape)
                worst = (float(d.max()), (b.t, scene.object_ids[m], int(k)))
    assert worst[0] <= INVARIANT_DEPTH, f"deepest {worst[0]:.4f} m at (t, object, particle) {worst[1]}"
