"""The same run from Python: the estimator as a library, a belief per reasoning step."""
import dataclasses

import numpy as np

from estimator.config import default_config
from estimator.filter import SceneEstimator
from estimator.observations import ObservationReader
from physics import load_scene

scene = load_scene("scene.yaml")
config = default_config(particles=32)                 # the particle filter's defaults, K = 32 worlds
config = dataclasses.replace(config, workers=0)       # ... stepped in this process
with SceneEstimator(scene, config, np.random.default_rng(0)) as estimator:
    for frame in ObservationReader("observations.jsonl", scene.object_ids):
        belief = estimator.update(frame)              # None between reasoning steps
        if belief is not None and frame.t >= 1.5 and round(frame.t * 30) % 15 == 0:
            cup = belief.objects["cup"]
            r2 = cup.region(0.9)                      # the 90 % region: an ellipsoid
            print(f"t = {belief.t:.2f} s: cup perceived {cup.perceived}, "
                  f"P(on the table) {belief.hypothesis_p('cup', 'isOnTop', 'table'):.2f}, "
                  f"90 % region radius along x {np.sqrt(r2 * cup.position_cov[0, 0]) * 100:.1f} cm")
