"""What arrived since the last reasoning step: the frames' detections, cameras and hands.

A reasoning step runs at the time of the newest frame and uses, besides the perception memory
(:class:`~estimator.model.perception_memory.PerceptionMemory`, which every frame updates), what the frames
since the previous step had in common: which objects were detected in any of them, which cameras took
them, the newest tracked hands. :class:`StepInputs` gathers that and is emptied by each step.
"""
from __future__ import annotations

import numpy as np

from ..worlds.shard import camera_key

__all__ = ["StepInputs"]


class StepInputs:
    """The frames recorded since the last reasoning step, for ``M`` objects.

    ``frame``: the newest frame (outliers dropped; None before any); ``t_frame`` its time (s);
    ``last_hands``: the tracked hands of the newest frame that had any (name -> ``(3,)`` m), kept
    across steps."""

    def __init__(self, M: int, scene_camera=None):
        self.M = M
        self.scene_camera = scene_camera
        self.frame = None
        self.t_frame: float | None = None
        self.last_hands: dict = {}
        self._detected = np.zeros(M, dtype=bool)
        self._cameras: dict | None = None  # the frames' own cameras since the last step, by key
        self._scene_camera_used = False  # a frame without cameras (the scene's) since then

    def check_time(self, t: float) -> None:
        """Raises ``ValueError`` unless ``t`` (s) comes after the newest frame's time."""
        if self.t_frame is not None and not t > self.t_frame:
            raise ValueError(f"frame time must increase: {t} after {self.t_frame}")

    def add(self, frame, detected: np.ndarray) -> None:
        """Record ``frame`` (already admitted), in which the objects ``detected (M,)`` bool were."""
        self.frame, self.t_frame = frame, frame.t
        self._detected |= detected
        if frame.hands:
            self.last_hands = dict(frame.hands)
        if frame.cameras is None:
            self._scene_camera_used = True
        else:
            own = self._cameras if self._cameras is not None else {}
            own.update((camera_key(c), c) for c in frame.cameras.values())
            self._cameras = own

    def take(self) -> tuple[np.ndarray, tuple | None]:
        """The objects detected since the last step ``(M,)`` bool, and the cameras that took the frames
        since then: None when every frame was the scene camera's (the pool asks the scene camera),
        else each distinct camera once (the scene's too if one frame was its). Empties both."""
        detected, self._detected = self._detected, np.zeros(self.M, dtype=bool)
        own, scene_cam = self._cameras, self._scene_camera_used
        self._cameras, self._scene_camera_used = None, False
        if own is None:
            return detected, None
        cams = list(own.values())
        if scene_cam and self.scene_camera is not None and camera_key(self.scene_camera) not in own:
            cams.insert(0, self.scene_camera)
        return detected, tuple(cams)
