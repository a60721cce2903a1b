"""The particle worlds: one persistent copy of the scene per particle slot, packed into a few pybullet
clients and sharded over worker processes (:mod:`~estimator.worlds.pool`), what each update does in
them (:mod:`~estimator.worlds.propagate`, :mod:`~estimator.worlds.held`, :mod:`~estimator.worlds.resting`)
and what they hold between updates (:mod:`~estimator.worlds.world_cache`)."""
