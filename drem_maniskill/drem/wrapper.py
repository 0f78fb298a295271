"""A gymnasium wrapper that gives any ManiSkill env a DREM reward from a checkpoint.

``DREMRewardWrapper(gym.make("PegInsertionSide-v1", ...), checkpoint)`` replaces the env's
reward with ``R(s)`` of a checkpoint trained on that env and keeps the original reward in
``info["original_reward"]``. Camera images come from the observation when it has them, else the
wrapper renders the checkpoint's cameras once per step; the F/T modality needs our wrist
sensor (``env.unwrapped.ft``).
"""

from __future__ import annotations

import gymnasium as gym
import torch

from drem_maniskill.drem.checkpoint import CheckpointError
from drem_maniskill.drem.reward import DREMReward


class DREMRewardWrapper(gym.Wrapper):
    """Replace a ManiSkill env's reward with a DREM reward; the old one goes to ``info``."""

    def __init__(self, env: gym.Env, checkpoint: str):
        super().__init__(env)
        self.reward_model = DREMReward.from_checkpoint(str(checkpoint), env=env)
        missing = [uid for uid in self.reward_model.camera_uids if uid not in env.unwrapped._sensors]
        if missing:
            raise CheckpointError(f"the env has no camera {missing}; the checkpoint needs {self.reward_model.camera_uids}")

    def _images(self, obs) -> dict:
        need = self.reward_model.camera_uids
        data = obs.get("sensor_data", {}) if isinstance(obs, dict) else {}
        if all("rgb" in data.get(uid, {}) for uid in need):
            return {uid: data[uid]["rgb"] for uid in need}
        u = self.env.unwrapped
        u.scene.update_render(update_sensors=True, update_human_render_cameras=False)
        for uid in need:
            u._sensors[uid].capture()
        return {uid: u._sensors[uid].get_obs(rgb=True, depth=False, position=False, segmentation=False)["rgb"] for uid in need}

    def reward(self, obs) -> torch.Tensor:
        """DREM reward ``[num_envs]`` of the env's current state."""
        images = self._images(obs)
        batch = {key: images[uid] for key, uid in self.reward_model.camera_of.items()}
        if "ft" in self.reward_model.model.config.modalities:
            batch["ft"] = self.env.unwrapped.ft.buffer
        return self.reward_model(batch)

    def step(self, action):
        """Step the env; reward replaced by DREM, original kept in ``info["original_reward"]``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        info["original_reward"] = reward
        return obs, self.reward(obs), terminated, truncated, info
