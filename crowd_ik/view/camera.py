"""The game's camera per frame: fixed where the scene puts it, or following the player.

camera.mode "follow": look_at tracks the player's pelvis and the scene's position - look_at is the
offset kept, both through one first-order low-pass with the time constant FOLLOW_TAU of *world*
time (in slow motion the camera drifts slowly too); it starts on the player. "fixed": the scene's
camera, unchanged. `camera` is a view.render.Camera (vertical fov_deg).
"""

from __future__ import annotations

import math

import numpy as np

from crowd_ik.view.render import Camera

FOLLOW_TAU = 0.5  # s of world time: the follow camera's low-pass time constant


class CameraRig:
    """The scene's camera settings (scene.camera), image size, and the follow state."""

    def __init__(self, settings, width: int, height: int, pelvis):
        self.mode = getattr(settings, "mode", "fixed")
        self.fov_deg = float(settings.fov_deg)
        self.size = (int(width), int(height))
        self.offset = np.asarray(settings.position, np.float64) - np.asarray(settings.look_at, np.float64)
        self.look_at = np.asarray(pelvis if self.mode == "follow" else settings.look_at, np.float64).copy()
        self.camera = self._make()

    def _make(self) -> Camera:
        return Camera(self.look_at + self.offset, self.look_at, self.fov_deg, *self.size)

    def update(self, pelvis, world_dt: float) -> None:
        """Follow the player's pelvis (3,) over world_dt s of world time (no change when fixed)."""
        if self.mode != "follow" or world_dt <= 0.0:
            return
        k = 1.0 - math.exp(-world_dt / FOLLOW_TAU)
        self.look_at = self.look_at + (np.asarray(pelvis, np.float64) - self.look_at) * k
        self.camera = self._make()
