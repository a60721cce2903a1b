"""The particle estimator: the scene model (``model``, ``holding``, ``noise``, ``hands``), the SMC
algorithm (``filter``), the belief it reports (``belief``) and the Kalman tracker it feeds
(``tracker``). A regular package, so that a copy of the project on ``PYTHONPATH`` is imported whole,
never mixed with an installed one."""
