"""What is built on the belief: uncertainty-aware hidden-object search (:mod:`~estimator.applications.search`),
the physics-aware pose tracker (:mod:`~estimator.applications.tracker`) and the view of a person in the
scene (:mod:`~estimator.applications.person`)."""
