"""Statistics over scenarios, seeds and methods (``scene-estimator evaluate``): the methods compared,
the trials and their checkpointed sweep, the metrics, the statistics, the report and its figures;
the held-object priors fitted on other seeds (``fit-priors``)."""
