"""The scene model: how the particles move between two updates, what physics reports back, and how a
particle is weighed; built from mechanisms (:mod:`estimator.model.mechanisms`).

The filter (:class:`~estimator.filter.SceneEstimator`) talks to it through
:class:`~estimator.model.scene_model.SceneModel` only. Its parts: the perception memory
(:mod:`~estimator.model.perception_memory`, :mod:`~estimator.model.detection_noise`,
:mod:`~estimator.model.hands`) and what arrived since the last update (:mod:`~estimator.model.inputs`);
the mechanisms and the array functions they call (:mod:`~estimator.model.motion`,
:mod:`~estimator.model.holding`, :mod:`~estimator.model.fusion`, :mod:`~estimator.model.noise`,
:mod:`~estimator.model.params`); after physics :mod:`~estimator.model.settle`; the weights
(:mod:`~estimator.model.weighing`, :mod:`~estimator.model.likelihood`); after resampling
:mod:`~estimator.model.regularisation`; what one update hands on (:mod:`~estimator.model.step`).
"""
from .scene_model import SceneModel, initial_poses

__all__ = ["SceneModel", "initial_poses"]
