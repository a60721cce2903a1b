"""Physics layer: scene files, pybullet worlds, poses in and out, contact, ray and AABB queries."""
from .errors import InputError, ObservationError, SceneError
from .scene import CameraSpec, ObjectSpec, Scene, load_scene, scene_from_dict, scene_to_dict
from .world import FLOOR, PhysicsSettings, World

__all__ = ["InputError", "ObservationError", "SceneError", "CameraSpec", "ObjectSpec", "Scene",
           "load_scene", "scene_from_dict", "scene_to_dict", "FLOOR", "PhysicsSettings", "World"]
