"""The hidden-object search experiment (``scene-estimator search-eval``): a simulated robot camera
looks for an object the scenario hid, following each method's plan; ground-truth visibility decides
when it is found."""
