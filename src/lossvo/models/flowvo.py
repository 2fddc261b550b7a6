"""FlowVO: a pose network on optical flow and the camera's intrinsics layer (after TartanVO, Wang et al.
2020), one frame pair at a time, with separate translation and rotation heads.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lossvo.checks import is_integer
from lossvo.console import UserError
from lossvo.geometry.camera import intrinsics_channels
from lossvo.models.arguments import check_float, check_int, dropout, memory_format, seeded_build
from lossvo.models.arguments import head_bias as head_bias_of

TOTAL_STRIDE = 16
"""Product of the encoder's strides: features are (ceil(H / pool / 16), ceil(W / pool / 16))."""
TRANSLATION_DIM = 3


class Residual(nn.Module):
    """Two 3x3 convs with BatchNorm, the first strided, beside a 1x1 strided shortcut; ReLU of the sum."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.branch = nn.Sequential(
            nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False),
            nn.BatchNorm2d(c_out),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_out, c_out, 3, padding=1, bias=False),
        )
        self.branch_norm = nn.BatchNorm2d(c_out)
        self.shortcut = nn.Sequential(
            nn.Conv2d(c_in, c_out, 1, stride=stride, bias=False), nn.BatchNorm2d(c_out)
        )

    def forward(self, x: Tensor) -> Tensor:
        return torch.relu(self.branch_norm(self.branch(x)) + self.shortcut(x))


class Head(nn.Module):
    """Dropout, a hidden layer with a leaky ReLU of slope ``negative_slope`` below zero (0: ReLU), a linear
    output."""

    def __init__(self, features: int, hidden: int, out: int, p: float, negative_slope: float) -> None:
        super().__init__()
        self.dropout = nn.Dropout(p)
        self.hidden = nn.Linear(features, hidden)
        self.out = nn.Linear(hidden, out)
        self.negative_slope = negative_slope

    def forward(self, x: Tensor) -> Tensor:
        return self.out(F.leaky_relu(self.hidden(self.dropout(x)), self.negative_slope))


class FlowVO(nn.Module):
    """Pose from optical flow and intrinsics, one frame pair at a time, translation and rotation heads apart::

        flow (B, P, 2, H, W) px   ->  flow * gain / (W, H)             scaled by the image size
        K (B, 3, 3)               ->  (x - cx) / fx, (y - cy) / fy      the intrinsics layer, (B, 2, H, W)
                                  ->  average-pooled by ``pool``        (B*P, 4, H/pool, W/pool)
                                  ->  encoder (B*P, C, H/16p, W/16p)    a stem, three residual stages
                                  ->  flattened features (B*P, F)       keeps where a motion is
                                  ->  translation head (B, P, 3)
                                      rotation head (B, P, out_dim - 3)

    P = L - 1 frame pairs of a window; the output is ``[t (3), r (D)]`` (:mod:`lossvo.losses`; for the
    SE(3) loss the first three are rho). The rotation follows from the flow and K alone (a rotation's flow
    does not depend on depth), the translation's length only through what the scene implies.

    ``flow_gain`` scales the flow to a fraction of the image of order 1; ``head_bias`` (out_dim,) is the
    loss's identity output (null: zeros); ``head_negative_slope`` > 0 gives leaky heads, whose units below
    zero still pass gradients; ``flow`` names the flow the network reads (``data.flow.method``), recorded
    with it; ``pool`` average-pools the encoder's input; ``channels_last`` runs it in NHWC, same values.
    """

    INPUTS = ("flow", "K")
    """The batch entries :meth:`forward` takes (:mod:`lossvo.data.datamodules`)."""

    _head_bias: Tensor
    _flow_scale: Tensor

    def __init__(
        self,
        out_dim: int,
        height: int,
        width: int,
        channels: Sequence[int] = (32, 64, 96, 128),
        hidden: int = 128,
        flow_gain: float = 20.0,
        head_dropout: float = 0.0,
        head_bias: list[float] | None = None,
        head_negative_slope: float = 0.0,
        flow: str = "dis",
        pool: int = 1,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        self.out_dim = check_int(
            "out_dim", out_dim, TRANSLATION_DIM + 1, " (3 translation outputs and a rotation)"
        )
        why = f" so that the encoder (stride {TOTAL_STRIDE}) has at least 1 {{}}"
        self.height = check_int("height", height, TOTAL_STRIDE, why.format("row"))
        self.width = check_int("width", width, TOTAL_STRIDE, why.format("column"))
        widths = list(channels) if isinstance(channels, Sequence) and not isinstance(channels, str) else []
        if len(widths) != 4 or not all(is_integer(c, 1) for c in widths):
            raise UserError(f"model.channels: expected 4 integers >= 1, got {channels!r}")
        self.channels = tuple(widths)
        self.hidden = check_int("hidden", hidden, 1)
        self.flow_gain = check_float("flow_gain", flow_gain, 0.0, math.inf, False, "a number > 0")
        p = dropout("head_dropout", head_dropout)
        self.head_negative_slope = check_float(
            "head_negative_slope", head_negative_slope, 0.0, 1.0, True, "a slope in [0, 1)"
        )
        self.flow = flow
        self.pool = check_int("pool", pool, 1)
        if self.height % self.pool or self.width % self.pool:
            raise UserError(
                f"model.pool: expected a divisor of the input size ({self.height}, {self.width}), got {pool}"
            )
        self.memory_format = memory_format(channels_last)
        self.register_buffer("_head_bias", head_bias_of(head_bias, self.out_dim), persistent=False)
        size = torch.tensor([self.width, self.height], dtype=torch.float32)  # the flow's divisor, per channel
        self.register_buffer("_flow_scale", (self.flow_gain / size).view(2, 1, 1), persistent=False)
        self.reset_parameters(seeded_build(lambda: self._build(p)))
        for part in (self.stem, self.stages):  # nn.Module.to takes memory_format; torch's overloads omit it
            part.to(memory_format=self.memory_format)  # type: ignore[call-overload]

    def _build(self, p: float) -> None:
        c0, c1, c2, c3 = self.channels
        self.stem = nn.Sequential(
            nn.Conv2d(4, c0, 5, stride=2, padding=2, bias=False),
            nn.BatchNorm2d(c0),
            nn.ReLU(inplace=True),
        )
        self.stages = nn.Sequential(Residual(c0, c1, 2), Residual(c1, c2, 2), Residual(c2, c3, 2))
        h, w = self.height // self.pool, self.width // self.pool
        self.feature_shape = (c3, -(-h // TOTAL_STRIDE), -(-w // TOTAL_STRIDE))
        features = math.prod(self.feature_shape)
        slope = self.head_negative_slope
        self.translation_head = Head(features, self.hidden, TRANSLATION_DIM, p, slope)
        self.rotation_head = Head(features, self.hidden, self.out_dim - TRANSLATION_DIM, p, slope)

    @torch.no_grad()
    def reset_parameters(self, seed: int) -> None:
        """Initialise every layer: the encoder and translation head (the same for every loss) from a
        generator seeded with ``seed``, the rotation head from one seeded with ``seed + 1``. Convs Kaiming
        normal (ReLU, fan-out); BatchNorm weight 1, bias 0, the last of each residual branch 0 (every stage
        starts as its shortcut); head layers Kaiming uniform (for the hidden units' slope), the last normal
        with std 1e-3 and the loss's identity output as bias."""
        backbone = torch.Generator().manual_seed(seed)
        rotation = torch.Generator().manual_seed(seed + 1)
        for m in (*self.stem.modules(), *self.stages.modules()):
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu", generator=backbone)
            elif isinstance(m, nn.BatchNorm2d):
                m.reset_parameters()  # running stats, weight 1, bias 0
        for stage in self.stages.modules():
            if isinstance(stage, Residual):
                nn.init.zeros_(stage.branch_norm.weight)  # each stage starts as its shortcut
        bias = self._head_bias.split([TRANSLATION_DIM, self.out_dim - TRANSLATION_DIM])
        for head, generator, b in (
            (self.translation_head, backbone, bias[0]),
            (self.rotation_head, rotation, bias[1]),
        ):
            nn.init.kaiming_uniform_(
                head.hidden.weight, a=head.negative_slope, nonlinearity="leaky_relu", generator=generator
            )
            nn.init.zeros_(head.hidden.bias)
            nn.init.normal_(head.out.weight, std=1e-3, generator=generator)
            head.out.bias.copy_(b)

    def extra_repr(self) -> str:
        return (
            f"out_dim={self.out_dim}, size=({self.height}, {self.width}), feature_shape={self.feature_shape}"
        )

    def encoder_input(self, flow: Tensor, K: Tensor) -> Tensor:
        """The encoder's input (B*P, 4, H/pool, W/pool) from flow (B, P, 2, H, W) and K (B, 3, 3) in pixels:
        the scaled flow and the intrinsics layer of each pair, average-pooled."""
        expected = f"(B, P, 2, {self.height}, {self.width})"
        if flow.dim() != 5 or flow.shape[2] != 2 or tuple(flow.shape[3:]) != (self.height, self.width):
            raise ValueError(f"FlowVO expects flow of shape {expected}, got {tuple(flow.shape)}")
        if K.shape != (flow.shape[0], 3, 3):
            raise ValueError(f"FlowVO expects K of shape ({flow.shape[0]}, 3, 3), got {tuple(K.shape)}")
        B, P = flow.shape[:2]
        scaled = self._pooled(flow.float().reshape(B * P, 2, self.height, self.width))
        scaled = scaled * self._flow_scale
        layer = self._pooled(intrinsics_channels(K.float(), self.height, self.width))  # once a window
        layer = layer[:, None].expand(B, P, *layer.shape[1:]).reshape(B * P, *layer.shape[1:])
        return torch.cat((scaled, layer), dim=1).contiguous(memory_format=self.memory_format)

    def _pooled(self, x: Tensor) -> Tensor:
        """(N, C, H, W) -> (N, C, H/pool, W/pool), the mean of each pool x pool block: a sum of strided
        slices (faster than ``avg_pool2d`` on a CPU for these few channels)."""
        p = self.pool
        return sum((x[..., i::p, j::p] for i in range(p) for j in range(p)), torch.zeros(())) / p**2

    def forward(self, flow: Tensor, K: Tensor) -> Tensor:
        """Outputs (B, P, out_dim), ``[t (3), r (out_dim - 3)]`` per pair, from flow (B, P, 2, H, W) in
        pixels and K (B, 3, 3)."""
        B, P = flow.shape[:2]
        x = self.stages(self.stem(self.encoder_input(flow, K))).flatten(1)
        out = torch.cat((self.translation_head(x), self.rotation_head(x)), dim=-1)
        return out.reshape(B, P, self.out_dim)
