"""The observation encoders of the networks in :mod:`bimgame.learn.nets`: observations (N, …) →
features (N, F).

- :class:`ConvEncoder` — the A3C paper's Conv-ReLU-Conv-ReLU-FC-ReLU on uint8 frames, optionally
  with each convolution's spatial soft-argmax keypoints (:class:`SpatialSoftArgmax`) as more FC
  inputs, an empty-maze background subtracted from each frame, and bfloat16 autocast;
- :class:`MLPEncoder` — two tanh layers on state vectors brought to order 1 by fixed divisors, a
  maze encoding entering the first layer through zero-initialised weights of its own, in the
  board's frame or turned into the marble's (:func:`marble_frame`);
- :class:`CyberRunnerEncoder` — CyberRunner's observation of the labyrinth in its flat form
  (:func:`~bimgame.envs.labyrinth_cyberrunner.flatten_cyberrunner`): the marble-centred 64×64 crop through the
  paper's two convolutions, the vector parts (tilt, position, path ahead) through a tanh layer, both
  into one FC layer.

The fixed inputs (``background``, ``scale``) are buffers: :func:`bimgame.learn.nets.build_network`
sets them, checkpoints carry them.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from bimgame.envs.labyrinth_cyberrunner import CROP_SIZE

__all__ = ["MAZE_FRAMES", "SpatialSoftArgmax", "ConvEncoder", "MLPEncoder", "CyberRunnerEncoder", "marble_frame"]

#: Frames a state network reads the maze encoding in: as observed (``board``: bin 0 at board angle
#: -π) or turned so that it starts at the marble's angle (``marble``; see :func:`marble_frame`).
MAZE_FRAMES = ("board", "marble")


class SpatialSoftArgmax(nn.Module):
    """(N, C, H, W) activations → (N, 2C) expected (x, y) per channel in [-1, 1], with a learned
    temperature per channel."""

    grid: torch.Tensor
    """(H·W, 2) the (x, y) of each activation, row by row."""

    def __init__(self, channels: int, height: int, width: int):
        super().__init__()
        self.log_temperature = nn.Parameter(torch.zeros(channels))
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c = x.shape[:2]
        weights = torch.softmax(x.reshape(n, c, -1) * self.log_temperature.exp().unsqueeze(-1), dim=-1)
        return (weights @ self.grid).reshape(n, 2 * c)


def _relu_init(*layers: nn.Conv2d | nn.Linear) -> None:
    """Orthogonal weights with ReLU's gain and zero biases: the image encoders' layers."""
    for layer in layers:
        nn.init.orthogonal_(layer.weight, gain=nn.init.calculate_gain("relu"))
        if layer.bias is not None:  # all have one; a convolution's is typed optional
            nn.init.zeros_(layer.bias)


class _ImageEncoder(nn.Module):
    """An encoder whose ``_features`` may run under bfloat16 autocast (``bf16``; float32 features out)."""

    bf16: bool

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if not self.bf16:
            return self._features(obs)
        with torch.autocast(obs.device.type, dtype=torch.bfloat16):
            return self._features(obs).float()

    def _features(self, obs: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError


class ConvEncoder(_ImageEncoder):
    """uint8 frames (N, C, H, W) → features (N, F): Conv-ReLU-Conv-ReLU-FC-ReLU, optionally with
    the convolutions' spatial soft-argmax keypoints as more FC inputs.

    ``obs_shape`` is one frame's (C, H, W), ``conv_channels`` the two convolutions' widths,
    ``features`` F; ``bf16`` runs the encoder under bfloat16 autocast (float32 features out)."""

    background: torch.Tensor
    """(C, H, W) subtracted from each frame (zeros unless the network subtracts the empty maze)."""

    def __init__(
        self,
        obs_shape: tuple[int, ...],
        conv_channels: tuple[int, int],
        features: int,
        *,
        keypoints: bool = False,
        bf16: bool = False,
    ):
        super().__init__()
        c, h, w = obs_shape
        c1, c2 = conv_channels
        self.conv1 = nn.Conv2d(c, c1, 8, stride=4)
        self.conv2 = nn.Conv2d(c1, c2, 4, stride=2)
        with torch.no_grad():
            a1 = self.conv1(torch.zeros(1, c, h, w))
            a2 = self.conv2(a1)
        flat = a2[0].numel()
        self.keypoints: nn.ModuleList | None = None
        if keypoints:
            self.keypoints = nn.ModuleList([SpatialSoftArgmax(c1, *a1.shape[2:]), SpatialSoftArgmax(c2, *a2.shape[2:])])
            flat += 2 * (c1 + c2)
        # LayerNorm before the last ReLU: a frame is mostly static maze, so without it the features
        # vary across states by ~1% of their size and the LSTM hears the marble as a whisper next to
        # its previous-action and tilt inputs (measured: per-unit std across states 0.0016 against
        # a mean of 0.015 with PyTorch's default init).
        linear = nn.Linear(flat, features)
        self.fc = nn.Sequential(linear, nn.LayerNorm(features), nn.ReLU())
        self.register_buffer("background", torch.zeros(obs_shape))
        self.bf16 = bf16
        _relu_init(self.conv1, self.conv2, linear)

    def _features(self, obs: torch.Tensor) -> torch.Tensor:
        a1 = self.conv1((obs.float() - self.background) * (1.0 / 255.0))
        a2 = self.conv2(torch.relu(a1))
        parts = [torch.relu(a2).flatten(1)]
        if self.keypoints is not None:
            parts += [self.keypoints[0](a1), self.keypoints[1](a2)]
        return self.fc(torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0])


class MLPEncoder(nn.Module):
    """State vectors (N, D) → features (N, F): scale to order 1, then two tanh layers.

    With ``maze_size`` > 0 the last ``maze_size`` values are the maze's encoding
    (:func:`~bimgame.envs.mazes.maze_encoding`). They enter the first layer through weights of their
    own (``maze_weight``), which start at zero: an untrained network then acts as one without the
    encoding, and the state values keep the initial weights of a network of their own width. One
    first layer over all D inputs would draw every weight from PyTorch's ±1/√D, 4.4× smaller for
    the 7 state values beside a 128-value encoding, and would add the encoding's ~25 open bins as a
    large fixed input; measured, PPO then learned nothing on STG1 even on a single random maze (3%
    success after 300k steps) where the same run without the encoding reached 93% in 94k steps.
    The zeros are created, not drawn, so the weights after them are those of a network without
    the encoding from the same seed."""

    scale: torch.Tensor
    """(D,) the divisors that bring each state component to order 1 (ones unless set)."""

    def __init__(self, dim: int, features: int, maze_size: int = 0, maze_frame: str = "board"):
        super().__init__()
        if not 0 <= maze_size < dim:
            raise ValueError(
                f"MLPEncoder: maze_size must be in 0..{dim - 1} (the input has {dim} values), got {maze_size}"
            )
        if maze_frame not in MAZE_FRAMES:
            raise ValueError(f"MLPEncoder: unknown maze_frame {maze_frame!r}; allowed: {', '.join(MAZE_FRAMES)}")
        self.maze_size = maze_size
        self.maze_frame = maze_frame
        self.register_buffer("scale", torch.ones(dim))
        self.net = nn.Sequential(
            nn.Linear(dim - maze_size, features), nn.Tanh(), nn.Linear(features, features), nn.Tanh()
        )
        self.maze_weight = nn.Parameter(torch.zeros(features, maze_size)) if maze_size else None

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        scaled = obs.float() / self.scale
        if self.maze_weight is None:
            return self.net(scaled)
        state, maze = scaled[..., : -self.maze_size], scaled[..., -self.maze_size :]
        if self.maze_frame == "marble":
            maze = marble_frame(maze, torch.atan2(obs[..., 1].float(), obs[..., 0].float()))
        first = self.net[0](state) + nn.functional.linear(maze, self.maze_weight)
        return self.net[1:](first)


#: Angular bins per wall of the maze encoding (:data:`bimgame.envs.mazes.MAZE_ENCODING_ANGLES`;
#: a number here so that the networks do not import the envs).
ENCODING_BINS = 32


def marble_frame(encoding: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """The maze encoding (…, W·32) turned into the marble's frame: bin ``k`` of each wall then covers
    the angles ``[θ - π + kΔ, θ - π + (k + 1)Δ)`` around the marble's angle ``θ`` (…) instead of
    ``[-π + kΔ, …)``, read from the board-frame bins by linear interpolation (the bins are a ring).

    Why: in the board's frame, where the marble stands in the encoding depends on its angle, so a
    policy must learn the product of position and encoding to find the gate nearest to the marble;
    in the marble's frame the nearest gates are always in the same bins (those around 16), and a
    linear read-out of the encoding says which way round they are."""
    bins = ENCODING_BINS
    shape = encoding.shape
    walls = encoding.reshape(-1, shape[-1] // bins, bins)
    # θ - π is board bin θ/Δ (bin 0 starts at -π), so ego bin k reads board bin k + θ/Δ.
    shift = angle.reshape(-1, 1) / (2 * math.pi / bins)
    position = torch.arange(bins, dtype=walls.dtype, device=walls.device) + shift
    low = torch.floor(position)
    weight = (position - low).unsqueeze(1)
    low_index = low.long().remainder(bins).unsqueeze(1).expand_as(walls)
    high_index = (low_index + 1).remainder(bins)
    turned = walls.gather(2, low_index) * (1 - weight) + walls.gather(2, high_index) * weight
    return turned.reshape(shape)


class CyberRunnerEncoder(_ImageEncoder):
    """CyberRunner's flat observations (N, D) → features (N, F): the first ``crop_size``² values are
    the marble-centred crop (0–255, row by row), the other D − ``crop_size``² the vector parts
    (tilt / 10°, position / board size, the path ahead / k·12 mm: already of order 1), as
    :func:`~bimgame.envs.labyrinth_cyberrunner.flatten_cyberrunner` lays them out.

    - crop: /255, then the A3C paper's Conv 16×8×8 stride 4 - ReLU - Conv 32×4×4 stride 2 - ReLU
      (``conv_channels``); on 64×64 they leave 32 × 6 × 6 = 1152 values, each seeing 40 × 40 mm of
      the 64 mm window (a 12 mm marble, walls and holes around it);
    - vector parts: Linear(D − crop², ``vector_width``) - tanh (the state network's first layer);
    - both concatenated into Linear(1152 + ``vector_width``, F) - LayerNorm - ReLU (the conv
      network's FC layer, whose LayerNorm keeps the features' spread up: :class:`ConvEncoder`).

    CyberRunner's DreamerV3 read the crop (colour, 64×64×3) with its own CNN and the vector with an
    MLP; this is the same split at the size of the paper's A3C network. ``bf16`` runs the encoder
    under bfloat16 autocast (float32 features out)."""

    def __init__(
        self,
        dim: int,
        conv_channels: tuple[int, int],
        features: int,
        *,
        crop_size: int = CROP_SIZE,
        vector_width: int = 64,
        bf16: bool = False,
    ):
        super().__init__()
        pixels = crop_size * crop_size
        if not (crop_size >= 16 and dim > pixels):
            raise ValueError(
                f"CyberRunnerEncoder: the input must hold a crop of {crop_size}×{crop_size} >= 16×16 pixels and "
                f"at least one vector value, got {dim} values"
            )
        self.crop_size, self.vector_size = crop_size, dim - pixels
        c1, c2 = conv_channels
        self.conv1 = nn.Conv2d(1, c1, 8, stride=4)
        self.conv2 = nn.Conv2d(c1, c2, 4, stride=2)
        with torch.no_grad():
            flat = self.conv2(self.conv1(torch.zeros(1, 1, crop_size, crop_size)))[0].numel()
        self.vector = nn.Sequential(nn.Linear(self.vector_size, vector_width), nn.Tanh())
        linear = nn.Linear(flat + vector_width, features)
        self.fc = nn.Sequential(linear, nn.LayerNorm(features), nn.ReLU())
        self.bf16 = bf16
        _relu_init(self.conv1, self.conv2, linear)

    def split(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The crops (N, 1, S, S) and vector parts (N, V) of flat observations (N, D)."""
        obs = obs.float()
        pixels = self.crop_size * self.crop_size
        crop = obs[..., :pixels].reshape(-1, 1, self.crop_size, self.crop_size)
        return crop, obs[..., pixels:].reshape(-1, self.vector_size)

    def _features(self, obs: torch.Tensor) -> torch.Tensor:
        crop, vector = self.split(obs)
        a2 = torch.relu(self.conv2(torch.relu(self.conv1(crop * (1.0 / 255.0)))))
        return self.fc(torch.cat([a2.flatten(1), self.vector(vector)], dim=-1))
