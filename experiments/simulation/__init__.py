"""Simulated scenarios with ground truth: the simulator (a person's hands moving objects in one
pybullet world), the synthetic camera and the perception model that turn its truth into an
observation stream."""
