"""DeepVO (Wang et al., ICRA 2017): a FlowNetS encoder on stacked frame pairs, an LSTM over the pairs and
a linear head, one relative-pose vector ``[t (3), r (D)]`` per frame pair (:mod:`lossvo.losses`).
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from pathlib import Path

import torch
from torch import Tensor, nn

from lossvo.console import UserError
from lossvo.models.arguments import check_float, check_int, dropout, memory_format, seeded_build
from lossvo.models.arguments import head_bias as head_bias_of
from lossvo.models.flownet import load_flownet

log = logging.getLogger(__name__)

LSTMState = tuple[Tensor, Tensor]
"""(h, c), each (lstm_layers, B, hidden_size)."""

# FlowNetS contracting part: (name, in_channels, out_channels, kernel, stride); channels before width_mult.
FLOWNETS_ENCODER: tuple[tuple[str, int, int, int, int], ...] = (
    ("conv1", 6, 64, 7, 2),
    ("conv2", 64, 128, 5, 2),
    ("conv3", 128, 256, 5, 2),
    ("conv3_1", 256, 256, 3, 1),
    ("conv4", 256, 512, 3, 2),
    ("conv4_1", 512, 512, 3, 1),
    ("conv5", 512, 512, 3, 2),
    ("conv5_1", 512, 512, 3, 1),
    ("conv6", 512, 1024, 3, 2),
)
TOTAL_STRIDE = 64
"""Product of the encoder's strides: conv6 features are (ceil(H / 64), ceil(W / 64))."""


def _conv_block(c_in: int, c_out: int, kernel: int, stride: int, batch_norm: bool, p: float) -> nn.Sequential:
    """FlowNetPytorch's ``conv()`` block plus dropout: indices 0 conv, 1 BN (or identity), 2 act, 3 drop."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=(kernel - 1) // 2, bias=not batch_norm),
        nn.BatchNorm2d(c_out) if batch_norm else nn.Identity(),
        nn.LeakyReLU(0.1, inplace=True),
        nn.Dropout(p),
    )


class DeepVO(nn.Module):
    """DeepVO: FlowNetS encoder on stacked frame pairs, a stacked LSTM over the pairs, a linear head::

        frames (B, L, 3, H, W)  ->  pairs (B, L-1, 6, H, W)         frames k and k+1 stacked on channels
                                ->  encoder (B*(L-1), C6, H6, W6)    FlowNetS conv1..conv6, one batched call
                                ->  LSTM (B, L-1, hidden_size)       over the L-1 pairs of each window
                                ->  head (B, L-1, out_dim)           [t (3), r (D)]

    with ``H6 = ceil(H / 64)``, ``W6 = ceil(W / 64)``, ``C6 = round(1024 * width_mult)``. The encoder is
    FlowNetS's contracting part (Dosovitskiy et al. 2015), named as in FlowNetPytorch so that
    :func:`~lossvo.models.flownet.load_flownet` loads its weights (``flownet``: a checkpoint path; needs
    ``width_mult=1``, ``batch_norm`` as in the file and ``normalization: flownet`` input). Training resets
    the LSTM state for every window; :meth:`forward_with_state` carries it across chunks. The dropouts are
    DeepVO-pytorch's defaults; ``head_bias`` (out_dim,) is the loss's identity output (null: zeros);
    ``channels_last`` runs the encoder in NHWC, the same values (with conv dropout, other masks).
    """

    INPUTS = ("frames",)
    """The batch entries :meth:`forward` takes (:mod:`lossvo.data.datamodules`)."""

    _head_bias: Tensor  # a buffer (register_buffer); nn.Module's __getattr__ would type it Tensor | Module

    def __init__(
        self,
        out_dim: int,
        height: int,
        width: int,
        width_mult: float = 1.0,
        hidden_size: int = 1000,
        lstm_layers: int = 2,
        conv_dropout: float = 0.2,
        conv6_dropout: float = 0.5,
        lstm_dropout: float = 0.5,
        head_dropout: float = 0.5,
        batch_norm: bool = True,
        flownet: str | Path | None = None,
        head_bias: list[float] | None = None,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        why = f" so that conv6 (stride {TOTAL_STRIDE}) has at least 1 {{}}"
        self.out_dim = check_int("out_dim", out_dim, 1)
        self.height = check_int("height", height, TOTAL_STRIDE, why.format("row"))
        self.width = check_int("width", width, TOTAL_STRIDE, why.format("column"))
        self.width_mult = check_float("width_mult", width_mult, 0.0, 16.0, False, "a number in (0, 16]")
        self.hidden_size = check_int("hidden_size", hidden_size, 1)
        self.lstm_layers = check_int("lstm_layers", lstm_layers, 1)
        conv_p = dropout("conv_dropout", conv_dropout)
        conv6_p = dropout("conv6_dropout", conv6_dropout)
        lstm_p = dropout("lstm_dropout", lstm_dropout)
        head_p = dropout("head_dropout", head_dropout)
        if not isinstance(batch_norm, bool):
            raise UserError(f"model.batch_norm: expected true or false, got {batch_norm!r}")
        if flownet is not None and not isinstance(flownet, (str, Path)):
            raise UserError(f"model.flownet: expected a path or null, got {flownet!r}")
        self.memory_format = memory_format(channels_last)
        self.register_buffer("_head_bias", head_bias_of(head_bias, self.out_dim), persistent=False)

        init_seed = seeded_build(lambda: self._build(conv_p, conv6_p, lstm_p, head_p, batch_norm))
        self.reset_parameters(init_seed)
        # nn.Module.to takes memory_format (documented, and at run time); torch's overloads omit it.
        self.encoder.to(memory_format=self.memory_format)  # type: ignore[call-overload]

        if flownet is not None:
            report = load_flownet(self, flownet)
            log.info("DeepVO encoder from FlowNet checkpoint %s: %s", flownet, report.summary())

    def _build(self, conv_p: float, conv6_p: float, lstm_p: float, head_p: float, batch_norm: bool) -> None:
        """Create the layers (encoder, LSTM, head)."""
        blocks: OrderedDict[str, nn.Module] = OrderedDict()
        for name, c_in, c_out, kernel, stride in FLOWNETS_ENCODER:
            c_in = c_in if name == "conv1" else self._channels(c_in)
            p = conv6_p if name == "conv6" else conv_p
            blocks[name] = _conv_block(c_in, self._channels(c_out), kernel, stride, batch_norm, p)
        self.encoder = nn.Sequential(blocks)

        self.feature_shape: tuple[int, int, int] = (
            self._channels(FLOWNETS_ENCODER[-1][2]),
            -(-self.height // TOTAL_STRIDE),
            -(-self.width // TOTAL_STRIDE),
        )
        """(C6, H6, W6) of the conv6 features of one pair."""
        self.lstm_input_size = math.prod(self.feature_shape)
        self.lstm = nn.LSTM(
            self.lstm_input_size,
            self.hidden_size,
            num_layers=self.lstm_layers,
            batch_first=True,
            dropout=lstm_p if self.lstm_layers > 1 else 0.0,
        )
        self.head_dropout = nn.Dropout(head_p)
        self.head = nn.Linear(self.hidden_size, self.out_dim)

    def _channels(self, c: int) -> int:
        return max(1, round(c * self.width_mult))

    @torch.no_grad()
    def reset_parameters(self, seed: int) -> None:
        """Initialise every layer: encoder and LSTM from a generator seeded with ``seed``, the head from
        ``seed + 1``, so every head size gets the same backbone.

        Convs Kaiming normal (LeakyReLU(0.1), fan-in); LSTM Xavier-uniform input and orthogonal recurrent
        weights per gate, forget-gate ``bias_hh`` 1; head weights normal with std 1e-3 and bias
        ``head_bias`` (an all-zero output is degenerate for the quaternion and 6-D decodings).
        """
        backbone = torch.Generator().manual_seed(seed)
        head = torch.Generator().manual_seed(seed + 1)
        for m in self.encoder.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, a=0.1, nonlinearity="leaky_relu", generator=backbone)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                m.reset_parameters()  # running stats, weight 1, bias 0
        n = self.hidden_size
        for name, param in self.lstm.named_parameters():
            if name.startswith("weight_ih"):
                for gate in param.split(n):  # PyTorch gate order: input, forget, cell, output
                    nn.init.xavier_uniform_(gate, generator=backbone)
            elif name.startswith("weight_hh"):
                for gate in param.split(n):
                    nn.init.orthogonal_(gate, generator=backbone)
            elif name.startswith("bias"):
                nn.init.zeros_(param)
                if name.startswith("bias_hh"):
                    param[n : 2 * n] = 1.0
        nn.init.normal_(self.head.weight, std=1e-3, generator=head)
        self.head.bias.copy_(self._head_bias)

    def extra_repr(self) -> str:
        return (
            f"out_dim={self.out_dim}, size=({self.height}, {self.width}), width_mult={self.width_mult:g}, "
            f"feature_shape={self.feature_shape}"
        )

    def _check_frames(self, frames: Tensor) -> None:
        expected = f"(B, L >= 2, 3, {self.height}, {self.width})"
        if not isinstance(frames, Tensor):
            raise ValueError(f"DeepVO expects frames as a tensor of shape {expected}, got {type(frames)}")
        shape = tuple(frames.shape)
        if len(shape) != 5 or shape[0] < 1 or shape[1] < 2 or shape[2:] != (3, self.height, self.width):
            raise ValueError(f"DeepVO expects frames of shape {expected}, got {shape}")
        if not frames.is_floating_point():
            raise ValueError(f"DeepVO expects normalised floating-point frames, got dtype {frames.dtype}")

    def features(self, frames: Tensor) -> Tensor:
        """Flattened conv6 features (B, L-1, lstm_input_size) of the consecutive pairs of ``frames``.

        Pair k stacks frames k and k+1 on the channel axis (frame k first); the encoder runs once on all
        B * (L-1) pairs.
        """
        self._check_frames(frames)
        B, L = frames.shape[:2]
        pairs = torch.cat((frames[:, :-1], frames[:, 1:]), dim=2)  # (B, L-1, 6, H, W)
        pairs = pairs.reshape(B * (L - 1), 6, self.height, self.width).contiguous(
            memory_format=self.memory_format
        )
        feats = self.encoder(pairs)
        return feats.reshape(B, L - 1, self.lstm_input_size)

    def forward_with_state(self, frames: Tensor, state: LSTMState | None = None) -> tuple[Tensor, LSTMState]:
        """Outputs (B, L-1, out_dim) for frames (B, L, 3, H, W) and the final LSTM state, starting from
        ``state`` ((h, c), each (lstm_layers, B, hidden_size); None: zeros). A full sequence runs in chunks
        that overlap by one frame (``[0, k]`` then ``[k, L-1]``), in ``eval()`` mode."""
        hidden, state = self.lstm(self.features(frames), state)
        return self.head(self.head_dropout(hidden)), state

    def forward(self, frames: Tensor, state: LSTMState | None = None) -> Tensor:
        """Outputs (B, L-1, out_dim) for frames (B, L, 3, H, W); the LSTM starts from ``state`` or zeros."""
        return self.forward_with_state(frames, state)[0]
