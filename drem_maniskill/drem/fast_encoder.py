"""The reward's encoder ``h(s)`` rearranged for speed: same weights, same function as ``DREMModel.encode``."""

from __future__ import annotations

import threading
from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

from drem_maniskill.drem.model import DREMModel

class FastEncoder:
    """The reward's encoder ``h(s)`` rearranged for speed; same weights, same function.

    Built from a :class:`DREMModel` at load (``DREMReward`` rebuilds it when its weights change).
    At a handful of envs the encoder's cost is per-op overhead, and inside an env step every op
    also starts on caches the render has cooled, so it runs as few ops as it can:

    - images stay as the env gives them (``[B, H, W, 3]`` uint8, channels last) and are copied
      once into an int16 buffer; a downscale by an integer factor ``f`` to the model's size is a
      sum over ``f x f`` blocks (what area interpolation computes, exact in integers) written
      as floats straight into the first layer's zero-padded input, then one multiply by
      ``1 / (255 f^2)``;
    - every camera goes through its CNN in the same ops, the cameras stacked on a leading dim:
      a stride-2 4x4 conv with padding 1 is one copy of its input windows (im2col) and one
      batched matmul with the bias (``baddbmm``), whose activation is written into the next
      layer's padded input; the last, tiny conv layers are dense matrices (the conv applied to
      an identity basis);
    - the causal F/T convs are dense matrices over the time steps the newest output reads;
    - the linear layers with no nonlinearity between them (image ``fc``, the last F/T conv,
      ``fusion[0]``) are one matrix, and every branch writes its part of that matrix's input
      in place;
    - all intermediate tensors are buffers kept per thread, batch size and input layout.

    Matches ``model.encode(model.prepare(batch))`` to float rounding (tests/drem/test_fast_encoder.py).
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
            self.ft_layers, taps = self._ft_layers(model) if self.has_ft else ([], [])
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
            if self.has_ft:
                last = model.ft_encoder.net[-1]
                w0 = f0.weight[:, off : off + last.out_channels]
                weights.append(torch.cat([w0 @ last.weight[:, :, k] for k in taps], dim=1))
                bias += w0 @ last.bias
            self.fused_w = torch.cat(weights, dim=1).t().contiguous()
            self.fused_b = bias
            self.out_w, self.out_b = model.fusion[2].weight.t().contiguous(), model.fusion[2].bias.clone()
        self.image_features = len(self.cameras) * side * side * cfg.channels[-1] if self.cameras else 0
        self._local = threading.local()

    # --- construction ---

    def _image_layers(self, model: DREMModel) -> list:
        """Per conv layer ``(kind, side, c_in, c_out, weight [K, rows, cols], bias [K, 1, cols])``."""
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
                kind = "dense"
            else:
                # Rows in the order of an input window: (kernel row, kernel column, input channel).
                mats = [cv[i].weight.permute(2, 3, 1, 0).reshape(16 * cin, cout) for cv in convs]
                bias = [cv[i].bias for cv in convs]
                kind = "im2col"
            weight, bias = torch.stack(mats).contiguous(), torch.stack(bias)[:, None, :].contiguous()
            layers.append((kind, side, cin, cout, weight, bias))
            side = half
        return layers

    def _ft_layers(self, model: DREMModel):
        """Dense matrices of the causal convs between the time steps the newest output reads."""
        convs = [m for m in model.ft_encoder.net if isinstance(m, nn.Conv1d)]
        if len(convs) < 2 or any(cv.kernel_size != (2,) for cv in convs):
            raise ValueError("FastEncoder expects at least two kernel-2 causal F/T convs")
        T = model.config.ft_history
        # A kernel-2 causal conv with dilation d: out[t] = w[..., 0] x[t - d] + w[..., 1] x[t] + b.
        need = [[T - 1]]  # need[li]: the times of layer li's input that the newest output reads
        for cv in reversed(convs):
            d = cv.dilation[0]
            need.insert(0, sorted({u for t in need[0] for u in (t - d, t) if u >= 0}))
        need[0] = list(range(T))  # the raw history is read whole (unread steps get zero rows)
        layers = []
        for li, cv in enumerate(convs[:-1]):
            src, dst, d = need[li], need[li + 1], cv.dilation[0]
            w = cv.weight.new_zeros(len(src) * cv.in_channels, len(dst) * cv.out_channels)
            for j, t in enumerate(dst):
                for k, u in ((0, t - d), (1, t)):
                    if u >= 0:
                        i = src.index(u)
                        rows = slice(i * cv.in_channels, (i + 1) * cv.in_channels)
                        cols = slice(j * cv.out_channels, (j + 1) * cv.out_channels)
                        w[rows, cols] = cv.weight[:, :, k].t()
            if li == 0:
                w = w / float(model.ft_scale)  # the input scaling folded in
            layers.append((w.contiguous(), cv.bias.repeat(len(dst)).contiguous()))
        # The last conv at T - 1 reads its input at need[-2]: t - d (when not padding) and t.
        t, d = T - 1, convs[-1].dilation[0]
        taps = ([0] if t - d >= 0 else []) + [1]
        return layers, taps

    def to(self, device) -> "FastEncoder":
        """Move the weights (the work buffers follow, per device)."""
        for k, v in vars(self).items():
            if isinstance(v, torch.Tensor):
                setattr(self, k, v.to(device))
            elif k in ("layers", "ft_layers"):
                moved = [tuple(x.to(device) if isinstance(x, torch.Tensor) else x for x in item) for item in v]
                setattr(self, k, moved)
        return self

    # --- inference ---

    @staticmethod
    def _rgba_view(x: torch.Tensor) -> torch.Tensor:
        """``x`` ``[B, H, W, 3]`` itself, or the contiguous ``[B, H, W, 4]`` block it is a view of."""
        if x.is_contiguous() or x.stride()[1:] != (x.shape[2] * 4, 4, 1):
            return x
        if x.shape[0] > 1 and x.stride(0) != x.shape[1] * x.shape[2] * 4:
            return x
        if x.storage_offset() + x.numel() // 3 * 4 > x.untyped_storage().nbytes():
            return x
        return x.as_strided((*x.shape[:3], 4), (*x.stride()[:3], 1))

    def _buffers(self, shape: tuple, device) -> dict:
        """Work tensors for images ``shape`` ``(K, B, H, W, C)`` (zero padding written once)."""
        cache = getattr(self._local, "buffers", None)
        if cache is None:
            cache = self._local.buffers = {}
        key = (shape, device)
        if key in cache:
            return cache[key]
        K, B, H, W, C = shape
        S = self.size
        new = dict(device=device, dtype=self.fused_w.dtype)
        buf = {"z": torch.zeros(B, self.fused_w.shape[0], **new)}
        if self.cameras:
            # int16 holds the sums of 2 x 2 uint8 pixels exactly, in half a float's bytes.
            buf["images"] = torch.empty(shape, dtype=torch.int16, device=device)
            buf["rows"] = torch.empty(K, B, S, W, C, dtype=torch.int16, device=device)
            for li, (kind, side, cin, cout, w, b) in enumerate(self.layers):
                h = side // 2
                if kind == "im2col":
                    buf[li] = (
                        torch.zeros(K, B, side + 2, side + 2, cin, **new),
                        torch.empty(K, B * h * h, 16 * cin, **new),
                        torch.empty(K, B * h * h, cout, **new),
                    )
                else:
                    buf[li] = (torch.empty(K, B, side * side * cin, **new), None, torch.empty(K, B, w.shape[-1], **new))
        for li, (w, b) in enumerate(self.ft_layers):
            buf[f"ft{li}"] = torch.empty(B, w.shape[1], **new)
        cache[key] = buf
        return buf

    def _layer_input(self, buf: dict, li: int, K: int, B: int) -> torch.Tensor:
        """Where layer ``li``'s input lives, as ``[K, B, side, side, C]`` (after the last layer: ``z``)."""
        if li == len(self.layers):
            side = self.size // 2**li
            c = self.layers[-1][3]
            return buf["z"][:, : self.image_features].view(B, K, side, side, c).transpose(0, 1)
        kind, side, cin = self.layers[li][:3]
        if kind == "im2col":
            return buf[li][0][:, :, 1:-1, 1:-1]
        return buf[li][0].view(K, B, side, side, cin)

    def _images_into(self, sources: list, buf: dict, f: int) -> None:
        """Pool the camera images to the model's size, in [0, 1], into the first layer's input."""
        K, B = len(sources), sources[0].shape[0]
        dst = self._layer_input(buf, 0, K, B)
        if f == 1:
            for k, src in enumerate(sources):
                torch.mul(src[..., :3], 1.0 / 255.0, out=dst[k])
            return
        x = buf["images"]
        W, C = x.shape[-2:]
        for k, src in enumerate(sources):
            x[k].copy_(src)  # uint8 -> int16 in the copy
        S = self.size
        if f == 2:  # two adds of strided views: much cheaper than a reduction over a 6-d view
            rows = buf["rows"]
            x = x.view(K, B, S, 2, W, C)
            torch.add(x[:, :, :, 0], x[:, :, :, 1], out=rows)
            rows = rows.view(K, B, S, S, 2 * C)
            torch.add(rows[..., :3], rows[..., C : C + 3], out=dst)  # int16 sums, written as floats
        else:
            dst.copy_(x.view(K, B, S, f, S, f, C).sum((3, 5))[..., :3])
        dst.mul_(1.0 / (255.0 * f * f))

    def encode(self, batch: dict) -> Optional[torch.Tensor]:
        """Latent ``h(s)`` ``[B, latent]`` of raw inputs, or None when they need the general path."""
        B = next(iter(batch.values())).shape[0]
        if self.cameras:
            imgs = [batch[c] for c in self.cameras]
            first = imgs[0]
            if first.dim() != 4 or first.shape[-1] != 3 or first.dtype != torch.uint8:
                return None
            h, w = first.shape[1:3]
            if h != w or h % self.size or any(x.shape != first.shape or x.dtype != torch.uint8 for x in imgs):
                return None
            # Cameras hand out RGB as a view of RGBA (strides [..., 4, 1]): copying such a view
            # byte by byte is slow, so the whole RGBA block is read and the alpha dropped after.
            sources = [self._rgba_view(x) for x in imgs]
            if len({s.shape[-1] for s in sources}) > 1:
                sources = imgs
            K = len(imgs)
            buf = self._buffers((K, B, h, w, sources[0].shape[-1]), first.device)
            self._images_into(sources, buf, h // self.size)
            for li, (kind, side, cin, cout, wt, bias) in enumerate(self.layers):
                inp, cols, out = buf[li]
                half = side // 2
                if kind == "im2col":
                    s = inp.stride()
                    window_stride = (s[0], s[1], 2 * s[2], 2 * s[3], s[2], s[3], 1)
                    windows = inp.as_strided((K, B, half, half, 4, 4, cin), window_stride, inp.storage_offset())
                    cols.view(K, B, half, half, 4, 4, cin).copy_(windows)
                    inp = cols
                torch.baddbmm(bias, inp, wt, out=out)
                _leaky_relu_out(out.view(K, B, half, half, cout), self.slope, out=self._layer_input(buf, li + 1, K, B))
        else:
            buf = self._buffers((0, B, 0, 0, 0), batch["ft"].device)
        z = buf["z"]
        if self.has_ft:
            x = batch["ft"]
            x = x.reshape(B, -1) if x.dtype == z.dtype else x.to(z.dtype).reshape(B, -1)
            last = len(self.ft_layers) - 1
            for li, (wt, bias) in enumerate(self.ft_layers):
                y = torch.addmm(bias, x, wt, out=buf[f"ft{li}"])
                if li == last:
                    _leaky_relu_out(y, self.slope, out=z[:, self.image_features :])
                else:
                    x = F.leaky_relu_(y, self.slope)
        hidden = F.leaky_relu_(torch.addmm(self.fused_b, z, self.fused_w), self.slope)
        return torch.addmm(self.out_b, hidden, self.out_w)


# leaky_relu with an ``out=`` argument: writes the activation straight into the next input.
_leaky_relu_out = torch.ops.aten.leaky_relu.out
