"""The DREM reward (Eq. 2 of the paper) as a batched torch module.

``R(s) = 1 - d(h(s), h(s_G)) / d(h(s_0), h(s_G))`` with ``d`` the cosine distance and ``s_0``,
``s_G`` the expert's first and last observations (their embeddings are in the checkpoint).
``DREMReward.reward(env, obs)`` builds the model's inputs from a ManiSkill env and its
observation (the checkpoint's cameras, and the wrist F/T history when the model reads it) and
returns a ``[num_envs]`` tensor, without gradients. Every route of DREM into an env step (the
``drem`` reward mode, ``DREMRewardWrapper``) goes through it.
"""

from __future__ import annotations

import operator
from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

# The checkpoint finders are importable beside the reward that reads them (the README's examples do).
from drem_maniskill.drem.checkpoint import (  # noqa: F401
    CheckpointError,
    check_compatible,
    default_checkpoint,
    load_checkpoint,
    resolve_checkpoint,
)
from drem_maniskill.drem.fast_encoder import FastEncoder
from drem_maniskill.drem.model import CAMERA_OF, DREMModel, ModelConfig, check_normaliser, cosine_distance
from drem_maniskill.utils.cameras import camera_images
from drem_maniskill.utils.state import scene_poses

_VERSION = operator.attrgetter("_version")

# What an env pays for R(s) (``drem_form``): the paper's R itself, or R - 1, which is <= 0 and 0
# only at the goal. Under episodes that end at success a positive per-step reward pays an agent
# for not finishing (every step it stays collects more); with R - 1 every step before the goal
# costs and ending the episode costs nothing, as with the Engineered reward. Same ordering of
# states; without termination the two give the same optimal policy.
DREM_FORMS = {"paper": 0.0, "shifted": -1.0}


def check_form(form: str) -> str:
    """``form`` if it is a key of ``DREM_FORMS``, else a ValueError naming the choices."""
    if form not in DREM_FORMS:
        raise ValueError(f"unknown drem_form {form!r}; choose one of {list(DREM_FORMS)} "
                         "('shifted': R - 1, for episodes that end at success)")
    return form


def apply_form(reward: torch.Tensor, form: str) -> torch.Tensor:
    """``reward`` as ``form`` pays it (``DREM_FORMS``)."""
    offset = DREM_FORMS[form]
    return reward + offset if offset else reward


class DREMReward(nn.Module):
    """Task progress reward from a DREM checkpoint; call with an observation batch."""

    def __init__(self, header: dict, weights: dict):
        super().__init__()
        self.header = header
        config = ModelConfig.from_dict(header["model"])
        self.model = DREMModel(config)
        state = {k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")}
        missing, unexpected = self.model.load_state_dict(state, strict=False)
        if missing or unexpected:
            raise CheckpointError(f"checkpoint weights do not match its model config: missing {missing[:5]}, "
                                  f"unexpected {unexpected[:5]}")
        self.register_buffer("h_goal", weights["h_goal"].float())
        self.register_buffer("h_start", weights["h_start"].float())
        check_normaliser(self.h_start, self.h_goal, f"The DREM checkpoint for {header.get('env_id')}")
        uids = header.get("camera_uids") or [CAMERA_OF[c] for c in config.cameras]
        # Built once at load: the env step reads them.
        self._camera_pairs = tuple(zip(config.cameras, uids))
        self._uids = tuple(uids)
        self.model.eval()
        self.requires_grad_(False)

    @classmethod
    def from_checkpoint(cls, path: str, env=None) -> "DREMReward":
        """Load ``path``; with ``env`` given, check that the checkpoint fits it first."""
        header, weights = load_checkpoint(path)
        if env is not None:
            u = env.unwrapped
            cams = {uid: (s.config.height, s.config.width) for uid, s in u._sensors.items()}
            ft = getattr(u, "ft_history", None) if hasattr(u, "ft") else None
            env_id = getattr(u, "env_id", "") or (u.spec.id if u.spec else type(u).__name__)
            check_compatible(header, env_id, cams, ft, str(path))
        reward = cls(header, weights)
        if env is not None and reward.uses_poses:
            size, want = scene_poses(env.unwrapped.get_state_dict()).shape[1], reward.model.config.poses_size
            if size != want:
                raise CheckpointError(f"{path} reads {want} scene-pose values, this {env_id} scene has {size}: it was "
                                      "trained on another task or scene; build a reward for this one")
        if env is not None:
            missing = [uid for uid in reward.camera_uids if uid not in cams]
            if missing:
                raise CheckpointError(f"the env has no camera {missing}; "
                                      f"the checkpoint {path} needs {reward.camera_uids}")
            reward = reward.to(env.unwrapped.device)
        return reward

    @property
    def camera_uids(self) -> list:
        """Camera uids the model reads."""
        return [self.camera_of[c] for c in self.model.config.cameras]

    @property
    def camera_of(self) -> dict:
        """Image modality -> camera uid, as the checkpoint was trained (``base_camera`` on stock tasks)."""
        return dict(self.camera_pairs)

    @property
    def camera_pairs(self) -> tuple:
        """``camera_of`` as ``(modality, uid)`` pairs, built once at load: the env step reads it."""
        return self._camera_pairs

    @property
    def uses_ft(self) -> bool:
        """Whether the model reads the wrist F/T history."""
        return "ft" in self.model.config.modalities

    @property
    def uses_poses(self) -> bool:
        """Whether the model reads the scene's poses (``utils.state.scene_poses``)."""
        return "poses" in self.model.config.modalities

    def inputs(self, env, obs) -> dict:
        """The model's raw inputs for ``env``'s current state: the checkpoint's camera images from ``obs``
        (rendered once when it has none), the wrist F/T history and the scene's poses when the model reads them."""
        images = camera_images(env, obs, self._uids) if self._uids else {}
        batch = {key: images[uid] for key, uid in self._camera_pairs}
        if self.uses_ft:
            batch["ft"] = env.unwrapped.ft.buffer
        if self.uses_poses:
            batch["poses"] = scene_poses(env.unwrapped.get_state_dict())
        return batch

    def reward(self, env, obs) -> torch.Tensor:
        """``R(s)`` ``[num_envs]`` of ``env``'s current state, ``obs`` its observation of it.

        Its inputs stay in ``last_inputs`` until the next call: what else reads this state's images
        (``drem.guard.SupportGuard``) takes them from there rather than rendering the cameras again.
        """
        self.last_inputs = self.inputs(env, obs)
        return self(self.last_inputs)

    # Batches up to this size take the fast encoder; larger ones the model's convs (oneDNN),
    # which win once the work per op outweighs the per-op overhead (measured on 2 CPU cores).
    FAST_MAX_BATCH = 8

    @staticmethod
    def _batch_size(batch: dict) -> int:
        return next(iter(batch.values())).shape[0]

    def _apply(self, fn, *args, **kwargs):
        # .to() / .cuda() / .double() replace the tensors: the fast encoder is rebuilt from them.
        self._fast_tensors = None
        return super()._apply(fn, *args, **kwargs)

    def fast_encoder(self) -> Optional[FastEncoder]:
        """The fast encoder of the current weights (rebuilt after ``.to()``, ``load_state_dict`` or edits; None for a
        model reading poses)."""
        tensors = getattr(self, "_fast_tensors", None)
        if tensors is None:
            m = self.model  # what h(s) reads; the decoders do not count
            parts = (m.image_encoders, m.fusion) + ((m.ft_encoder,) if hasattr(m, "ft_encoder") else ())
            tensors = (*(t for p in parts for t in p.parameters()), m.ft_scale, self.h_start, self.h_goal)
            self._fast_tensors = tensors
            self._fast_key = None
        # In-place changes (load_state_dict, optimiser steps, edits) bump a tensor's version;
        # moving the model's own tensors (``reward.model.to(...)``) changes their storage.
        key = (*map(_VERSION, tensors), *map(torch.Tensor.data_ptr, tensors))
        if self._fast_key != key:
            # The fast path covers the paper's inputs; a model reading poses takes the reference path.
            self._fast_encoder = None if self.uses_poses else FastEncoder(self.model)
            with torch.no_grad():
                # Eq. 2's constants, computed once with the same ops as forward_reference.
                self._goal_unit = F.normalize(self.h_goal[None], dim=-1)
                self._scale = cosine_distance(self.h_start[None], self.h_goal[None]).clamp(min=1e-6)
                self._one = torch.ones((), dtype=self._scale.dtype, device=self._scale.device)
            self._fast_key = key
        return self._fast_encoder

    @torch.no_grad()
    def embed_reference(self, batch: dict) -> torch.Tensor:
        """``h(s)`` by the straightforward path, ``model.encode(model.prepare(batch))``."""
        inputs = self.model.prepare(batch)
        first = next(iter(inputs.values()))
        # oneDNN's per-call set-up dominates for a handful of samples on the CPU (measured:
        # 3.3 ms with it, 1.8 ms without, for one env); large batches keep it.
        small_cpu = first.device.type == "cpu" and first.shape[0] < 8
        with torch.backends.mkldnn.flags(enabled=not small_cpu):
            return self.model.encode(inputs)

    @torch.no_grad()
    def embed(self, batch: dict) -> torch.Tensor:
        """Latent ``h(s)`` ``[B, 128]`` of raw inputs (uint8 images of any size, F/T)."""
        # A CPU-simulated env rendering on a GPU hands out CUDA images and CPU F/T (seen on an H200):
        # the inputs go where the model is.
        dev = self.h_goal.device
        if any(v.device != dev for v in batch.values()):
            batch = {k: v.to(dev) for k, v in batch.items()}
        fast = self.fast_encoder()
        h = None
        if fast is not None and self._batch_size(batch) < self.FAST_MAX_BATCH:
            if self.h_goal.device.type == "cpu":
                # Each op here is too small to split over threads: a second thread only adds
                # wake-ups (measured 1.7 vs 2.0 ms per reward with 2 cores, under load).
                threads = torch.get_num_threads()
                torch.set_num_threads(1)
                try:
                    h = fast.encode(batch)
                finally:
                    torch.set_num_threads(threads)
            else:
                h = fast.encode(batch)
        return self.embed_reference(batch) if h is None else h

    @torch.no_grad()
    def forward(self, batch: dict) -> torch.Tensor:
        """``R(s)`` ``[B]`` of raw inputs."""
        h = self.embed(batch)
        # 1 - d(h, h_G) / d(h_0, h_G) with the unit goal and the normaliser precomputed, in the
        # reference's order of ops: d(h_0, h_G) can be tiny (a barely trained model), so any other
        # rounding of the cosine (a matmul's sum order, folding 1 / d(h_0, h_G) into the goal) is
        # amplified by as much (measured: 0.025 on the tiny pipeline's checkpoint). Written with
        # fewer ops, each giving the same floats: F.normalize's h / max(|h|, 1e-12), then
        # 1 + (cos - 1) / d(h_0, h_G), which is 1 - (1 - cos) / d(h_0, h_G) exactly.
        norm = torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp_min_(1e-12)
        cos = torch.div(h, norm).mul_(self._goal_unit).sum(-1)
        return torch.addcdiv(self._one, cos.sub_(1.0), self._scale)

    @torch.no_grad()
    def forward_reference(self, batch: dict) -> torch.Tensor:
        """``R(s)`` by the straightforward path (Eq. 2 as written), for tests and comparisons."""
        h = self.embed_reference(batch)
        scale = cosine_distance(self.h_start[None], self.h_goal[None]).clamp(min=1e-6)
        return 1.0 - cosine_distance(h, self.h_goal[None]) / scale
