"""Recurrent actor-critic networks: the paper's Conv-Conv-FC-LSTM on pixels and an MLP-LSTM on
state observations.

Both share one recurrent core (:class:`RecurrentActorCritic`): an observation encoder, then an LSTM
cell that also receives the previous action (one-hot; all zeros at an episode's first step), the
previous reward and — by default — the board's tilt, then two linear heads, π(a|s) (logits) and
V(s).

Why the tilt: an 84×84 frame shows where the marble is but not how the board is tilted, and the
actions change the tilt by ±1 step. The paper's network must integrate its own past actions in the
LSTM to know the tilt; a robot reads it from its joint encoders. ``tilt_input=False`` gives the
paper's inputs exactly.

Two entry points, one set of weights:

- :meth:`RecurrentActorCritic.step` — one time step for a batch of environments (acting: an
  ``LSTMCell`` call, fast at batch 1);
- :meth:`RecurrentActorCritic.unroll` — a whole segment (T, B): the encoder runs once on all T·B
  observations (one large convolution instead of T small ones), then the LSTM cell runs over time,
  zeroing its state wherever an episode starts. This is what the learners backpropagate through.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from bimgame.envs.env import NO_ACTION
from bimgame.sim.maze import MazeSpec
from bimgame.sim.render import MazeRenderer
from bimgame.util.settings import from_dict

__all__ = ["NetConfig", "RecurrentActorCritic", "ValueNetwork", "build_value_network", "LSTMState", "build_network", "state_obs_scale", "maze_background",
           "NO_ACTION", "N_ACTIONS", "ENCODERS"]

#: The discrete action set of the env (noop, ±x, ±y).
N_ACTIONS = 5
ENCODERS = ("conv", "mlp")


class LSTMState(NamedTuple):
    """Hidden and cell state, each (B, hidden)."""
    h: torch.Tensor
    c: torch.Tensor


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Sizes of the actor-critic. Defaults are the A3C paper's Atari LSTM network, which the
    BiMGame paper used: Conv 16×8×8 stride 4, Conv 32×4×4 stride 2, FC 256, LSTM 256."""

    encoder: str = "conv"
    """``conv`` (pixels, the paper's) or ``mlp`` (state observations)."""
    obs_shape: tuple[int, ...] = (1, 84, 84)
    """One observation's shape: (channels, height, width) for conv, (features,) for mlp."""
    conv_channels: tuple[int, int] = (16, 32)
    features: int = 256
    """Width of the FC layer after the convolutions, and of the two MLP layers."""
    hidden: int = 256
    """LSTM size."""
    n_actions: int = N_ACTIONS
    tilt_input: bool = True
    """Feed the board tilt (2 numbers, in units of the maximum tilt) to the LSTM."""
    subtract_background: bool = False
    """Conv encoder only: subtract the empty maze (walls, floor, goal: a fixed image, since frames
    are drawn in the board's frame) from each frame, so only the marble remains. The image then
    varies only where the state does, instead of the marble being ~5 px of difference on a
    high-contrast wall pattern."""
    keypoints: bool = False
    """Conv encoder only: also feed the FC layer each conv channel's spatial soft-argmax (the
    expected image position of its activation; Levine et al. 2016), so the marble's position is
    one linear map away from the features instead of something the FC layer must discover."""

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"unknown encoder {self.encoder!r}; allowed: {', '.join(ENCODERS)}")
        shape = tuple(int(s) for s in self.obs_shape)
        object.__setattr__(self, "obs_shape", shape)
        object.__setattr__(self, "conv_channels", tuple(int(c) for c in self.conv_channels))
        if self.encoder == "conv" and (len(shape) != 3 or min(shape[1:]) < 16):
            raise ValueError(f"conv encoder needs obs_shape (channels, height, width) with sides >= 16, "
                             f"got {shape}")
        if self.encoder == "mlp" and len(shape) != 1:
            raise ValueError(f"mlp encoder needs obs_shape (features,), got {shape}")
        for name in ("features", "hidden", "n_actions"):
            if getattr(self, name) < 1:
                raise ValueError(f"NetConfig.{name} must be >= 1, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> NetConfig:
        return from_dict(cls, values, "network settings")


def state_obs_scale(spec: MazeSpec, n_marbles: int = 1) -> np.ndarray:
    """Divisors that bring a state observation (see :class:`~bimgame.envs.observe.Observer`) to order 1:
    positions by the rim radius, velocities by 0.5 m/s (about the fastest reachable), tilts by the
    maximum tilt, channels by the outermost channel."""
    per_marble = [spec.rim_radius, spec.rim_radius, 0.5, 0.5] * n_marbles
    return np.array(per_marble + [spec.max_tilt] * 2 + [max(1, spec.outermost_channel)] * n_marbles,
                    dtype=np.float32)


class SpatialSoftArgmax(nn.Module):
    """(N, C, H, W) activations → (N, 2C) expected (x, y) per channel in [-1, 1], with a learned
    temperature per channel."""

    def __init__(self, channels: int, height: int, width: int):
        super().__init__()
        self.log_temperature = nn.Parameter(torch.zeros(channels))
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, c = x.shape[:2]
        weights = torch.softmax(x.reshape(n, c, -1) * self.log_temperature.exp().unsqueeze(-1), dim=-1)
        return (weights @ self.grid).reshape(n, 2 * c)


class ConvEncoder(nn.Module):
    """uint8 frames (N, C, H, W) → features (N, F): Conv-ReLU-Conv-ReLU-FC-ReLU, optionally with
    the convolutions' spatial soft-argmax keypoints as more FC inputs."""

    def __init__(self, config: NetConfig):
        super().__init__()
        c, h, w = config.obs_shape
        c1, c2 = config.conv_channels
        self.conv1 = nn.Conv2d(c, c1, 8, stride=4)
        self.conv2 = nn.Conv2d(c1, c2, 4, stride=2)
        with torch.no_grad():
            a1 = self.conv1(torch.zeros(1, c, h, w))
            a2 = self.conv2(a1)
        flat = a2[0].numel()
        self.keypoints = None
        if config.keypoints:
            self.keypoints = nn.ModuleList([SpatialSoftArgmax(c1, *a1.shape[2:]), SpatialSoftArgmax(c2, *a2.shape[2:])])
            flat += 2 * (c1 + c2)
        # LayerNorm before the last ReLU: a frame is mostly static maze, so without it the features
        # vary across states by ~1% of their size and the LSTM hears the marble as a whisper next to
        # its previous-action and tilt inputs (measured: per-unit std across states 0.0016 against
        # a mean of 0.015 with PyTorch's default init).
        self.fc = nn.Sequential(nn.Linear(flat, config.features), nn.LayerNorm(config.features), nn.ReLU())
        self.register_buffer("background", torch.zeros(config.obs_shape))
        for layer in (self.conv1, self.conv2, self.fc[0]):
            nn.init.orthogonal_(layer.weight, gain=nn.init.calculate_gain("relu"))
            nn.init.zeros_(layer.bias)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        a1 = self.conv1((obs.float() - self.background) * (1.0 / 255.0))
        a2 = self.conv2(torch.relu(a1))
        parts = [torch.relu(a2).flatten(1)]
        if self.keypoints is not None:
            parts += [self.keypoints[0](a1), self.keypoints[1](a2)]
        return self.fc(torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0])


class MLPEncoder(nn.Module):
    """State vectors (N, D) → features (N, F): scale to order 1, then two tanh layers."""

    def __init__(self, config: NetConfig):
        super().__init__()
        (dim,) = config.obs_shape
        self.register_buffer("scale", torch.ones(dim))
        self.net = nn.Sequential(nn.Linear(dim, config.features), nn.Tanh(),
                                 nn.Linear(config.features, config.features), nn.Tanh())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs.float() / self.scale)


class RecurrentActorCritic(nn.Module):
    """Encoder → LSTM cell (with previous action, previous reward, tilt) → policy and value heads."""

    def __init__(self, config: NetConfig):
        super().__init__()
        self.config = config
        self.encoder = ConvEncoder(config) if config.encoder == "conv" else MLPEncoder(config)
        self.aux_size = config.n_actions + 1 + (2 if config.tilt_input else 0)
        self.lstm = nn.LSTMCell(config.features + self.aux_size, config.hidden)
        self.policy = nn.Linear(config.hidden, config.n_actions)
        self.value = nn.Linear(config.hidden, 1)
        self._init_weights()

    def _init_weights(self) -> None:
        # Small policy logits start the policy near uniform (maximum entropy), as in the A3C
        # reference implementations; LSTM biases zero.
        nn.init.normal_(self.policy.weight, std=0.01)
        nn.init.zeros_(self.policy.bias)
        nn.init.normal_(self.value.weight, std=1.0 / np.sqrt(self.config.hidden))
        nn.init.zeros_(self.value.bias)
        nn.init.zeros_(self.lstm.bias_ih)
        nn.init.zeros_(self.lstm.bias_hh)

    def initial_state(self, batch: int) -> LSTMState:
        zeros = torch.zeros(batch, self.config.hidden)
        return LSTMState(zeros, zeros.clone())

    def aux_inputs(self, prev_action: torch.Tensor, prev_reward: torch.Tensor,
                   tilt: torch.Tensor | None) -> torch.Tensor:
        """(…,) previous actions (NO_ACTION allowed), (…,) previous rewards, (…, 2) tilts in units of
        the maximum tilt → (…, aux_size)."""
        valid = prev_action >= 0
        one_hot = nn.functional.one_hot(prev_action.long().clamp(min=0), self.config.n_actions)
        one_hot = one_hot * valid.unsqueeze(-1)
        parts = [one_hot.float(), prev_reward.float().unsqueeze(-1)]
        if self.config.tilt_input:
            if tilt is None:
                raise ValueError("this network takes the board tilt as input (tilt_input=True); pass tilt")
            parts.append(tilt.float())
        return torch.cat(parts, dim=-1)

    def step(self, obs: torch.Tensor, prev_action: torch.Tensor, prev_reward: torch.Tensor,
             tilt: torch.Tensor | None, state: LSTMState) -> tuple[torch.Tensor, torch.Tensor, LSTMState]:
        """One time step for B environments → logits (B, A), values (B,), next state."""
        x = torch.cat([self.encoder(obs), self.aux_inputs(prev_action, prev_reward, tilt)], dim=-1)
        h, c = self.lstm(x, state)
        return self.policy(h), self.value(h).squeeze(-1), LSTMState(h, c)

    def unroll(self, obs: torch.Tensor, prev_action: torch.Tensor, prev_reward: torch.Tensor,
               tilt: torch.Tensor | None, state: LSTMState, starts: torch.Tensor,
               ) -> tuple[torch.Tensor, torch.Tensor, LSTMState]:
        """A segment of T steps for B environments → logits (T, B, A), values (T, B), final state.

        ``starts`` (T, B) marks the first step of an episode: the LSTM state is zeroed there (the
        previous action and reward inputs should then be NO_ACTION and 0)."""
        steps, batch = obs.shape[:2]
        features = self.encoder(obs.reshape(steps * batch, *obs.shape[2:])).reshape(steps, batch, -1)
        x = torch.cat([features, self.aux_inputs(prev_action, prev_reward, tilt)], dim=-1)
        keep = (~starts).float().unsqueeze(-1)
        h, c = state
        outputs = []
        for t in range(steps):
            h, c = self.lstm(x[t], (h * keep[t], c * keep[t]))
            outputs.append(h)
        hidden = torch.stack(outputs)
        return self.policy(hidden), self.value(hidden).squeeze(-1), LSTMState(h, c)


class ValueNetwork(nn.Module):
    """V̂(s): the value-only network whose frozen values shape A3C's reward (the paper's "value
    function as a reward").

    Feed-forward on purpose: the shaping potential must be a function of the state for potential
    shaping to leave the optimal policies unchanged (Ng et al. 1999) — a recurrent V̂ would be a
    function of the history — and a reward wrapper then needs no per-environment memory. It sees
    what the agent's network sees of the state: the observation (the same encoder as
    :class:`RecurrentActorCritic`) and, with ``tilt_input``, the board tilt."""

    def __init__(self, config: NetConfig):
        super().__init__()
        self.config = config
        self.encoder = ConvEncoder(config) if config.encoder == "conv" else MLPEncoder(config)
        extra = 2 if config.tilt_input else 0
        self.head = nn.Sequential(nn.Linear(config.features + extra, config.hidden), nn.ReLU(),
                                  nn.Linear(config.hidden, 1))

    def forward(self, obs: torch.Tensor, tilt: torch.Tensor | None) -> torch.Tensor:
        """(N, …) observations and (N, 2) tilts in units of the maximum tilt → (N,) values."""
        x = self.encoder(obs)
        if self.config.tilt_input:
            if tilt is None:
                raise ValueError("this value network takes the board tilt as input (tilt_input=True); pass tilt")
            x = torch.cat([x, tilt.float()], dim=-1)
        return self.head(x).squeeze(-1)


def _configure_inputs(net: nn.Module, config: NetConfig, obs_scale: np.ndarray | None,
                      background: np.ndarray | None) -> None:
    """Set the encoder's fixed inputs: the empty-maze background (conv) or the state scale (mlp)."""
    if config.subtract_background:
        if background is None or np.shape(background) != config.obs_shape:
            raise ValueError(f"subtract_background needs the empty-maze frame of shape {config.obs_shape} "
                             f"(background=maze_background(spec)), got "
                             f"{None if background is None else np.shape(background)}")
        net.encoder.background.copy_(torch.as_tensor(np.asarray(background, dtype=np.float32)))
    elif background is not None:
        raise ValueError("background is only used with NetConfig(subtract_background=True)")
    if obs_scale is not None:
        if config.encoder != "mlp":
            raise ValueError("obs_scale applies to the mlp encoder only")
        scale = torch.as_tensor(np.asarray(obs_scale, dtype=np.float32))
        if scale.shape != net.encoder.scale.shape or not torch.all(scale > 0):
            raise ValueError(f"obs_scale must be {tuple(net.encoder.scale.shape)} positive numbers, "
                             f"got shape {tuple(scale.shape)}")
        net.encoder.scale.copy_(scale)


def build_value_network(config: NetConfig, obs_scale: np.ndarray | None = None, *, seed: int = 0,
                        background: np.ndarray | None = None) -> ValueNetwork:
    """A fresh :class:`ValueNetwork`; arguments as :func:`build_network`."""
    return _build(ValueNetwork, config, obs_scale, seed, background)


def build_network(config: NetConfig, obs_scale: np.ndarray | None = None, *, seed: int = 0,
                  background: np.ndarray | None = None) -> RecurrentActorCritic:
    """A fresh network with initial weights drawn from ``seed`` (the global torch generator is
    left untouched); ``obs_scale`` sets the MLP encoder's input divisors (see
    :func:`state_obs_scale`); ``background`` is the empty-maze frame a ``subtract_background``
    network subtracts (see :func:`maze_background`)."""
    return _build(RecurrentActorCritic, config, obs_scale, seed, background)


def _build(cls: type, config: NetConfig, obs_scale: np.ndarray | None, seed: int,
           background: np.ndarray | None):
    """``cls(config)`` with initial weights drawn from ``seed`` (the global torch generator is left
    untouched), then the encoder's fixed inputs set."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = cls(config)
    _configure_inputs(net, config, obs_scale, background)
    return net


def maze_background(spec: MazeSpec, size: int = 84) -> np.ndarray:
    """The observation frame without a marble, (1, size, size) uint8."""
    return MazeRenderer(spec, size).gray(np.zeros((0, 2)))[None]
