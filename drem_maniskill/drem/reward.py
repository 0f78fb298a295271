"""The DREM reward (Eq. 2 of the paper) as a batched torch module.

``R(s) = 1 - d(h(s), h(s_G)) / d(h(s_0), h(s_G))`` with ``d`` the cosine distance and ``s_0``,
``s_G`` the expert's first and last observations (their embeddings are in the checkpoint).
Observations of ``num_envs`` envs in, a ``[num_envs]`` tensor out, without gradients.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

from drem_maniskill.drem.checkpoint import CheckpointError, check_compatible, load_checkpoint
from drem_maniskill.drem.model import CAMERA_OF, DREMModel, ModelConfig, cosine_distance

# rewards/ sits beside the package in a checkout (editable install); a wheel installs it as
# data files under <prefix>/share/drem-maniskill/rewards (pyproject's data-files).
REWARDS_DIRS = (Path(__file__).resolve().parents[2] / "rewards", Path(sys.prefix) / "share" / "drem-maniskill" / "rewards")


class FastEncoder:
    """The reward's encoder ``h(s)`` rearranged for speed; same weights, same function.

    Built from a :class:`DREMModel` at load (``DREMReward`` rebuilds it when its weights change).
    At a handful of envs the encoder's cost is per-op overhead, so it runs fewer, larger ops:

    - images stay as the env gives them (``[B, H, W, 3]`` uint8, channels last); a downscale by
      an integer factor ``f`` to the model's size is a sum over ``f x f`` blocks (what area
      interpolation computes), and ``1 / (255 f^2)`` is one multiply;
    - every camera goes through its CNN in the same op, the cameras stacked on a leading dim:
      a stride-2 4x4 conv with padding 1 is a space-to-depth of the padded map and one batched
      matmul (``bmm``) whose four 2x2 output blocks are summed; the last, tiny conv layers are
      dense matrices (the conv applied to an identity basis);
    - the causal F/T convs are evaluated only at the time steps the newest output depends on;
    - the linear layers with no nonlinearity between them (image ``fc``, the last F/T conv,
      ``fusion[0]``) are one matrix;
    - the unit goal embedding and the normaliser ``d(h(s_0), h(s_G))`` are precomputed.

    Matches ``model.encode(model.prepare(batch))`` to float rounding (tests/test_reward_speed_paths.py).
    """

    # Conv layers with in x out sizes up to this become one dense matrix (only the last one at
    # 64 px: larger ones are memory-bound when an env step has just flushed the caches).
    DENSE_MAX = 100_000

    def __init__(self, model: DREMModel):
        cfg = model.config
        self.cameras = cfg.cameras
        self.size = cfg.image_size
        self.has_ft = "ft" in cfg.modalities
        self.slope = 0.1
        with torch.no_grad():
            self.layers = self._image_layers(model) if self.cameras else []
            self.ft_layers, ft_out_times = self._ft_layers(model) if "ft" in cfg.modalities else ([], 0)
            self.ft_scale = 1.0 / float(model.ft_scale)
            # fusion[0] o (per-camera fc, last F/T conv): one linear map of the concatenation.
            f0 = model.fusion[0]
            weights, bias, off = [], f0.bias.detach().clone(), 0
            side = self.size // 2 ** len(cfg.channels)
            for c in self.cameras:
                fc = model.image_encoders[c].fc
                w0 = f0.weight[:, off : off + fc.out_features]
                off += fc.out_features
                # fc reads the conv output flattened as (C, h, w); here it is (h, w, C).
                w_fc = fc.weight.view(fc.out_features, -1, side, side).permute(0, 2, 3, 1).reshape(fc.out_features, -1)
                weights.append(w0 @ w_fc)
                bias += w0 @ fc.bias
            if "ft" in cfg.modalities:
                last = model.ft_encoder.net[-1]
                w0 = f0.weight[:, off : off + last.out_channels]
                taps = ft_out_times  # which taps of the last conv see real inputs (the other reads padding)
                weights.append(torch.cat([w0 @ last.weight[:, :, k] for k in taps], dim=1))
                bias += w0 @ last.bias
            self.fused_w = torch.cat(weights, dim=1).t().contiguous()
            self.fused_b = bias
            self.out_w, self.out_b = model.fusion[2].weight.t().contiguous(), model.fusion[2].bias.clone()

    # --- construction ---

    def _image_layers(self, model: DREMModel) -> list:
        convs = [[m for m in model.image_encoders[c].conv if isinstance(m, nn.Conv2d)] for c in self.cameras]
        layers, side = [], self.size
        for i in range(len(convs[0])):
            cin, cout = convs[0][i].in_channels, convs[0][i].out_channels
            half = side // 2
            n_in = side * side * cin
            if n_in * half * half * cout <= self.DENSE_MAX:
                # The conv as a dense map between channels-last flattened maps.
                eye = torch.eye(n_in, dtype=convs[0][i].weight.dtype, device=convs[0][i].weight.device)
                eye = eye.view(n_in, side, side, cin).permute(0, 3, 1, 2)
                mats = [F.conv2d(eye, cv[i].weight, None, 2, 1).permute(0, 2, 3, 1).reshape(n_in, -1) for cv in convs]
                bias = [cv[i].bias.repeat(half * half) for cv in convs]
                layers.append(("dense", torch.stack(mats).contiguous(), torch.stack(bias)[:, None, :]))
            else:
                # weight[o, i, 2a + p, 2b + q]: rows (p, q, i) of the space-to-depth input, cols (a, b, o).
                mats = [
                    cv[i].weight.view(cout, cin, 2, 2, 2, 2).permute(3, 5, 1, 2, 4, 0).reshape(4 * cin, 4 * cout) for cv in convs
                ]
                bias = [cv[i].bias for cv in convs]
                layers.append(("s2d", torch.stack(mats).contiguous(), torch.stack(bias)[:, None, None, None, :]))
            side = half
        return layers

    def _ft_layers(self, model: DREMModel):
        """Gather plans of the causal convs, restricted to what the newest step's output reads."""
        convs = [m for m in model.ft_encoder.net if isinstance(m, nn.Conv1d)]
        if any(cv.kernel_size != (2,) for cv in convs):
            raise ValueError("FastEncoder expects kernel-2 causal F/T convs")
        T = model.config.ft_history
        need = [[T - 1]]  # need[l]: times of layer l's output used above (l = len(convs) - 1 is the last)
        for cv in reversed(convs):
            d = cv.dilation[0]
            below = sorted({u for t in need[0] for u in (t - d, t) if u >= 0})
            need.insert(0, below)
        # need[0]: input times; need[l + 1]: output times of conv l.
        plans = []
        for l, cv in enumerate(convs[:-1]):
            src, d = need[l], cv.dilation[0]
            prev = [src.index(t - d) if t - d >= 0 else len(src) for t in need[l + 1]]
            cur = [src.index(t) for t in need[l + 1]]
            pairs = len(src) == 2 * len(cur) and prev == list(range(0, len(src), 2)) and cur == [p + 1 for p in prev]
            w = cv.weight.permute(0, 2, 1).reshape(cv.out_channels, -1).t().contiguous()  # rows (tap, c_in)
            plans.append((pairs, torch.tensor(prev), torch.tensor(cur), w, cv.bias.detach()))
        self.ft_input_times = torch.tensor(need[0])
        self.ft_input_all = need[0] == list(range(T))
        # The last conv at T - 1: its tap 0 reads t - d (padding when negative), tap 1 reads t.
        last, t = convs[-1], T - 1
        src = need[-2]
        self.ft_last_idx = torch.tensor(([src.index(t - last.dilation[0])] if t - last.dilation[0] >= 0 else []) + [src.index(t)])
        self.ft_last_all = self.ft_last_idx.tolist() == list(range(len(src)))
        taps = ([0] if t - last.dilation[0] >= 0 else []) + [1]
        return plans, taps

    def to(self, device) -> "FastEncoder":
        for k, v in vars(self).items():
            if isinstance(v, torch.Tensor):
                setattr(self, k, v.to(device))
            elif k in ("layers", "ft_layers"):
                setattr(self, k, [tuple(x.to(device) if isinstance(x, torch.Tensor) else x for x in item) for item in v])
        return self

    # --- inference ---

    def images(self, batch: dict) -> Optional[torch.Tensor]:
        """Camera images stacked ``[K, B, S, S, 3]`` floats in [0, 1], or None for other inputs."""
        imgs = [batch[c] for c in self.cameras]
        first = imgs[0]
        if first.dim() != 4 or first.shape[-1] != 3 or first.dtype != torch.uint8:
            return None
        h, w = first.shape[1:3]
        if h != w or h % self.size or any(x.shape != first.shape for x in imgs):
            return None
        f = h // self.size
        # Cameras hand out RGB as a view of RGBA (strides [..., 4, 1]): copying such a view
        # byte by byte is slow, so the whole RGBA block is pooled and the alpha dropped after.
        imgs = [self._rgba_view(x) for x in imgs]
        x = torch.stack(imgs).float() if len(imgs) > 1 else imgs[0][None].float()
        K, B, _, _, C = x.shape
        if f == 2:  # two adds of strided views: much cheaper than a reduction over a 6-d view
            x = x.view(K, B, self.size, 2, w, C)
            x = x[:, :, :, 0] + x[:, :, :, 1]
            x = x.view(K, B, self.size, self.size, 2 * C)
            x = x[..., :C] + x[..., C:]
        elif f > 2:
            x = x.view(K, B, self.size, f, self.size, f, C).sum((3, 5))
        if C != 3:
            return x[..., :3].mul(1.0 / (255.0 * f * f))
        return x.mul_(1.0 / (255.0 * f * f))

    @staticmethod
    def _rgba_view(x: torch.Tensor) -> torch.Tensor:
        """``x`` ``[B, H, W, 3]`` itself, or the contiguous ``[B, H, W, 4]`` block it is a view of."""
        if x.is_contiguous() or x.stride()[1:] != (x.shape[2] * 4, 4, 1) or x.shape[0] > 1 and x.stride(0) != x.shape[1] * x.shape[2] * 4:
            return x
        if x.storage_offset() + x.numel() // 3 * 4 > x.untyped_storage().nbytes():
            return x
        return x.as_strided((*x.shape[:3], 4), (*x.stride()[:3], 1))

    def _s2d_conv(self, x, w, b):
        K, B, H, W, C = x.shape
        x = F.pad(x, (0, 0, 1, 1, 1, 1))
        h2, w2 = H // 2 + 1, W // 2 + 1
        x = x.view(K, B, h2, 2, w2, 2, C).permute(0, 1, 2, 4, 3, 5, 6).reshape(K, B * h2 * w2, 4 * C)
        y = torch.bmm(x, w).view(K, B, h2, w2, w.shape[-1])
        co = w.shape[-1] // 4
        y = y[:, :, :-1, :-1, :co] + y[:, :, :-1, 1:, co : 2 * co] + y[:, :, 1:, :-1, 2 * co : 3 * co] + y[:, :, 1:, 1:, 3 * co :]
        return F.leaky_relu(y.add_(b), self.slope)

    def encode_images(self, x: torch.Tensor) -> torch.Tensor:
        """``[K, B, S, S, 3]`` in [0, 1] -> conv features ``[B, K * D]``, channels last per camera."""
        K, B = x.shape[:2]
        for kind, w, b in self.layers:
            if kind == "s2d":
                x = self._s2d_conv(x, w, b)
            else:
                x = F.leaky_relu(torch.baddbmm(b, x.reshape(K, B, -1), w), self.slope)
        return x.reshape(K, B, -1).transpose(0, 1).reshape(B, -1)

    def encode_ft(self, ft: torch.Tensor) -> torch.Tensor:
        """``[B, T, 6]`` raw F/T -> the inputs of the last causal conv at the newest step, ``[B, n * C]``."""
        B = ft.shape[0]
        x = ft if self.ft_input_all else ft[:, self.ft_input_times.to(ft.device)]
        x = x.float() * self.ft_scale
        for pairs, prev, cur, w, b in self.ft_layers:
            if pairs:
                x = x.reshape(B, -1, 2 * x.shape[-1])
            else:
                x = torch.cat([x, x.new_zeros(B, 1, x.shape[-1])], dim=1)
                x = torch.cat([x[:, prev], x[:, cur]], dim=-1)
            x = F.leaky_relu(torch.matmul(x, w).add_(b), self.slope)
        if not self.ft_last_all:
            x = x[:, self.ft_last_idx]
        return x.reshape(B, -1)

    def encode(self, batch: dict) -> Optional[torch.Tensor]:
        """Latent ``h(s)`` ``[B, latent]`` of raw inputs, or None when they need the general path."""
        parts = []
        if self.cameras:
            x = self.images(batch)
            if x is None:
                return None
            parts.append(self.encode_images(x))
        if self.has_ft:
            parts.append(self.encode_ft(batch["ft"]))
        z = torch.cat(parts, dim=1) if len(parts) > 1 else parts[0]
        z = F.leaky_relu(torch.addmm(self.fused_b, z, self.fused_w), self.slope)
        return torch.addmm(self.out_b, z, self.out_w)


def default_checkpoint(env_id: str, image_only: bool = False) -> Path:
    """Path of the shipped checkpoint for ``env_id`` (``rewards/<env_id>/drem.pt``)."""
    name = "drem_image.pt" if image_only else "drem.pt"
    for folder in REWARDS_DIRS:
        if (folder / env_id / name).exists():
            return folder / env_id / name
    return REWARDS_DIRS[0] / env_id / name


class DREMReward(nn.Module):
    """Task progress reward from a DREM checkpoint; call with an observation batch."""

    def __init__(self, header: dict, weights: dict):
        super().__init__()
        self.header = header
        config = ModelConfig(**header["model"])
        self.model = DREMModel(config)
        state = {k[len("model."):]: v for k, v in weights.items() if k.startswith("model.")}
        missing, unexpected = self.model.load_state_dict(state, strict=False)
        if missing or unexpected:
            raise CheckpointError(f"checkpoint weights do not match its model config: missing {missing[:5]}, unexpected {unexpected[:5]}")
        self.register_buffer("h_goal", weights["h_goal"].float())
        self.register_buffer("h_start", weights["h_start"].float())
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
        if env is not None:
            reward = reward.to(env.unwrapped.device)
        return reward

    @property
    def camera_uids(self) -> list:
        """Camera uids the model reads."""
        return [self.camera_of[c] for c in self.model.config.cameras]

    @property
    def camera_of(self) -> dict:
        """Image modality -> camera uid, as the checkpoint was trained (``base_camera`` on stock tasks)."""
        uids = self.header.get("camera_uids") or [CAMERA_OF[c] for c in self.model.config.cameras]
        return dict(zip(self.model.config.cameras, uids))

    def inputs_from_obs(self, obs: dict) -> dict:
        """Pick the model's inputs from a ManiSkill observation dict (``sensor_data`` + ``extra``)."""
        batch = {c: obs["sensor_data"][self.camera_of[c]]["rgb"] for c in self.model.config.cameras}
        if "ft" in self.model.config.modalities:
            batch["ft"] = obs["extra"]["ft"]
        return batch

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

    def _fast(self) -> FastEncoder:
        """The fast encoder of the current weights (rebuilt after ``.to()``, ``load_state_dict`` or edits)."""
        tensors = getattr(self, "_fast_tensors", None)
        if tensors is None:
            tensors = self._fast_tensors = (*self.model.parameters(), *self.model.buffers(), self.h_start, self.h_goal)
            self._fast_key = None
        # In-place changes (load_state_dict, optimiser steps, edits) bump a tensor's version;
        # moving the model's own tensors (``reward.model.to(...)``) changes their storage.
        key = [(t._version, t.data_ptr()) for t in tensors]
        if self._fast_key != key:
            self._fast_encoder = FastEncoder(self.model)
            with torch.no_grad():
                # Eq. 2's constants, computed once with the same ops as forward_reference.
                self._goal_unit = F.normalize(self.h_goal[None], dim=-1)
                self._scale = cosine_distance(self.h_start[None], self.h_goal[None]).clamp(min=1e-6)
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
        fast = self._fast()
        h = None
        if self._batch_size(batch) < self.FAST_MAX_BATCH:
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
        # reference's order: d(h_0, h_G) can be tiny (a barely trained model), and folding
        # 1 / d(h_0, h_G) into the goal would amplify rounding differences by as much.
        return 1.0 - (1.0 - (F.normalize(h, dim=-1) * self._goal_unit).sum(-1)) / self._scale

    @torch.no_grad()
    def forward_reference(self, batch: dict) -> torch.Tensor:
        """``R(s)`` by the straightforward path (Eq. 2 as written), for tests and comparisons."""
        h = self.embed_reference(batch)
        scale = cosine_distance(self.h_start[None], self.h_goal[None]).clamp(min=1e-6)
        return 1.0 - cosine_distance(h, self.h_goal[None]) / scale


def resolve_checkpoint(env_id: str, path: Optional[str], image_only: bool = False) -> Path:
    """The checkpoint to use: ``path`` if given, else the shipped default for ``env_id``."""
    if path:
        return Path(path)
    default = default_checkpoint(env_id, image_only)
    if not default.exists():
        raise CheckpointError(
            f"no DREM checkpoint ships for {env_id} (looked for {default}). Train one with "
            f"`drem-maniskill train-reward` and pass gym.make({env_id!r}, reward_mode='drem', drem_checkpoint=PATH)"
        )
    return default
