"""Recurrent actor-critic networks: the paper's Conv-Conv-FC-LSTM on pixels, an MLP-LSTM on state
observations, and a Conv+MLP-LSTM on CyberRunner's observations of the labyrinth.

Both share one recurrent core (:class:`RecurrentActorCritic`): an observation encoder, then an LSTM
cell that also receives the previous action (one-hot; all zeros at an episode's first step), the
previous reward and — by default — the board's tilt, then two linear heads, π(a|s) (logits) and
V(s).

``action_type="continuous"``: π is a diagonal Gaussian over the env's 2 tilt changes (mean from the
head, a learned ``log_std``), the previous action the executed 2-vector (:mod:`bimgame.learn.policy_heads`).

Why the tilt: an 84×84 frame shows where the marble is but not how the board is tilted, and the
actions change the tilt by ±1 step. The paper's network must integrate its own past actions in the
LSTM to know the tilt; a robot reads it from its joint encoders. ``tilt_input=False`` gives the
paper's inputs exactly.

Options beyond the paper's network (each off by default, so the defaults of :class:`NetConfig` are the
paper's network with the tilt input):

- ``aux_heads``: two linear heads read the simulator's state (the *privileged* state observation,
  see :class:`~bimgame.envs.observe.Observer`) back from the features — the frame head from the
  encoder's features (what the frames show: :mod:`bimgame.learn.privileged_state`), the memory head from the
  LSTM (everything: also velocities and tilt). Their regression loss (:meth:`RecurrentActorCritic.aux_loss`)
  is a training signal only: the policy still acts from pixels alone. Without it the encoder must
  find a ≈ 5 px marble on a high-contrast maze from the reward alone.
- ``asymmetric_critic``: the value head also reads the privileged state (through a small MLP).
  The critic is only used in training, so the policy stays a pixel policy; this departs from the
  paper, whose critic shares the actor's pixel inputs (Pinto et al. 2017, asymmetric actor-critic).
- ``precision="bf16"``: the encoder (convolutions and FC layer, most of the compute) runs under
  bfloat16 autocast and returns float32 features; the LSTM and heads stay float32.

Two entry points, one set of weights: :meth:`RecurrentActorCritic.step`, one time step for a batch
of environments (acting), and :meth:`RecurrentActorCritic.unroll`, a whole segment (T, B) that the
learners backpropagate through: the encoder (:mod:`bimgame.learn.encoders`) runs once on all T·B
observations, then the LSTM cell runs over time, zeroing its state wherever an episode starts.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple, TypeVar

import numpy as np
import torch
from torch import nn

from bimgame.envs.env import NO_ACTION
from bimgame.envs.puzzles import maze_obs_scale as state_obs_scale
from bimgame.learn.encoders import MAZE_FRAMES, ConvEncoder, CyberRunnerEncoder, MLPEncoder
from bimgame.learn.lstm_unroll import lstm_unroll
from bimgame.learn.policy_heads import LOG_STD_INIT, ActionDistribution, action_head, check_action_type
from bimgame.learn.privileged_state import STATE_LAYOUTS, frame_visible
from bimgame.sim.maze import MazeSpec
from bimgame.sim.render import MazeRenderer
from bimgame.util.settings import from_dict

__all__ = [
    "NetConfig",
    "PRECISIONS",
    "Unrolled",
    "frame_visible",
    "RecurrentActorCritic",
    "ValueNetwork",
    "build_value_network",
    "LSTMState",
    "build_network",
    "state_obs_scale",
    "maze_background",
    "NO_ACTION",
    "N_ACTIONS",
    "ENCODERS",
]

#: The discrete action set of the env (noop, ±x, ±y).
N_ACTIONS = 5
ENCODERS = ("conv", "mlp", "cyberrunner")
#: The encoder's compute precision: float32, or bfloat16 autocast (CPUs with AVX512-BF16 / AMX run it
#: ≈ 1.5× faster; see benchmarks/bench_a3c.py).
PRECISIONS = ("fp32", "bf16")


class LSTMState(NamedTuple):
    """Hidden and cell state, each (B, hidden)."""

    h: torch.Tensor
    c: torch.Tensor


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Sizes of the actor-critic. Defaults are the A3C paper's Atari LSTM network, which the
    BiMGame paper used: Conv 16×8×8 stride 4, Conv 32×4×4 stride 2, FC 256, LSTM 256."""

    encoder: str = "conv"
    """``conv`` (pixels, the paper's), ``mlp`` (state observations) or ``cyberrunner`` (:class:`CyberRunnerEncoder`)."""
    obs_shape: tuple[int, ...] = (1, 84, 84)
    """One observation's shape: (channels, height, width) for conv, (features,) for mlp and cyberrunner."""
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
    precision: str = "fp32"
    """Conv and cyberrunner encoders' compute: ``fp32`` or ``bf16`` (bfloat16 autocast, float32 features out)."""
    privileged_size: int = 0
    """Length of the privileged state vector (the state observation) the auxiliary heads predict and
    an asymmetric critic reads; 0: none (neither option is available)."""
    aux_heads: bool = False
    """Heads that predict the privileged state from the encoder's and the LSTM's features."""
    state_layout: str = "maze"
    """Whose state the privileged vector is (``STATE_LAYOUTS``: the maze's, the labyrinth's)."""
    asymmetric_critic: bool = False
    """The value head also reads the privileged state (training only; not the paper's)."""
    maze_size: int = 0
    """MLP only: the observation's last ``maze_size`` values are a maze encoding with weights of their own
    (:class:`~bimgame.learn.encoders.MLPEncoder`); 0: none (or, stored before this setting, plain inputs)."""
    maze_frame: str = "board"
    """With ``maze_size``: read the encoding as observed or turned to the marble's angle (``MAZE_FRAMES``)."""
    action_type: str = "discrete"
    """``discrete`` (``n_actions`` logits, the paper's) or ``continuous`` (a Gaussian over the env's
    2 tilt changes; see :mod:`bimgame.learn.policy_heads`). Stored settings without it are discrete."""

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"unknown encoder {self.encoder!r}; allowed: {', '.join(ENCODERS)}")
        shape = tuple(int(s) for s in self.obs_shape)
        object.__setattr__(self, "obs_shape", shape)
        object.__setattr__(self, "conv_channels", tuple(int(c) for c in self.conv_channels))
        if self.encoder == "conv" and (len(shape) != 3 or min(shape[1:]) < 16):
            raise ValueError(f"conv encoder needs obs_shape (channels, height, width) with sides >= 16, got {shape}")
        if self.encoder != "conv" and len(shape) != 1:
            raise ValueError(f"{self.encoder} encoder needs obs_shape (features,), got {shape}")
        for name in ("features", "hidden", "n_actions"):
            if getattr(self, name) < 1:
                raise ValueError(f"NetConfig.{name} must be >= 1, got {getattr(self, name)}")
        check_action_type("NetConfig", self.action_type)
        if self.maze_size and (self.encoder != "mlp" or not 0 < self.maze_size < shape[0]):
            raise ValueError(f"NetConfig.maze_size needs the mlp encoder and < {shape[0]} values, got {self.maze_size}")
        if self.maze_frame not in MAZE_FRAMES or (self.maze_frame != "board" and not self.maze_size):
            raise ValueError(
                f"NetConfig.maze_frame must be one of {MAZE_FRAMES} (not board: with maze_size), "
                f"got {self.maze_frame!r}"
            )
        if self.precision not in PRECISIONS:
            raise ValueError(f"NetConfig.precision must be one of {PRECISIONS}, got {self.precision!r}")
        if self.privileged_size < 0 or (self.privileged_size and (self.privileged_size - 2) % 5):
            raise ValueError(
                f"NetConfig.privileged_size must be 0 or a state observation's length 5·n + 2, "
                f"got {self.privileged_size}"
            )
        if self.state_layout not in STATE_LAYOUTS:
            raise ValueError(f"NetConfig.state_layout must be one of {STATE_LAYOUTS}, got {self.state_layout!r}")
        for name in ("aux_heads", "asymmetric_critic"):
            if getattr(self, name) and not self.privileged_size:
                raise ValueError(f"NetConfig.{name} needs privileged_size > 0 (the state observation's length)")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> NetConfig:
        return from_dict(cls, values, "network settings")


class Unrolled(NamedTuple):
    """What :meth:`RecurrentActorCritic.unroll_features` returns for a segment of T steps × B envs."""

    logits: torch.Tensor
    """(T, B, A) the policy head's output: logits, or a continuous network's Gaussian means (T, B, 2);
    :meth:`RecurrentActorCritic.distribution` makes π of it."""
    values: torch.Tensor
    """(T, B); NaN for an asymmetric critic given no privileged state."""
    state: LSTMState
    """The LSTM state after the last step."""
    features: torch.Tensor
    """(T, B, F) the encoder's output."""
    hidden: torch.Tensor
    """(T, B, H) the LSTM's output."""


def make_encoder(config: NetConfig) -> ConvEncoder | MLPEncoder | CyberRunnerEncoder:
    """The observation encoder ``config`` describes (see :mod:`bimgame.learn.encoders`)."""
    bf16 = config.precision == "bf16"
    if config.encoder == "cyberrunner":
        return CyberRunnerEncoder(config.obs_shape[0], config.conv_channels, config.features, bf16=bf16)
    if config.encoder == "conv":
        return ConvEncoder(
            config.obs_shape,
            config.conv_channels,
            config.features,
            keypoints=config.keypoints,
            bf16=bf16,
        )
    (dim,) = config.obs_shape
    return MLPEncoder(dim, config.features, config.maze_size, config.maze_frame)


class RecurrentActorCritic(nn.Module):
    """Encoder → LSTM cell (with previous action, previous reward, tilt) → policy and value heads;
    a continuous network also has ``log_std``, the Gaussian's learned log standard deviations."""

    log_std: nn.Parameter | None

    privileged_scale: torch.Tensor
    """(P,) divisors that bring the privileged state to order 1."""
    frame_index: torch.Tensor
    """With auxiliary heads: the indices of the privileged state one frame shows (:func:`frame_visible`)."""

    def __init__(self, config: NetConfig):
        super().__init__()
        self.config = config
        self.encoder = make_encoder(config)
        self.action_head = action_head(config.action_type, config.n_actions)
        self.side_size = self.action_head.input_size + 1 + (2 if config.tilt_input else 0)
        self.lstm = nn.LSTMCell(config.features + self.side_size, config.hidden)
        self.policy = nn.Linear(config.hidden, self.action_head.output_size)
        # No random draw: a discrete network's initial weights are what they were before log_std existed.
        self.log_std = None
        if config.action_type == "continuous":
            self.log_std = nn.Parameter(torch.full((self.action_head.output_size,), LOG_STD_INIT))
        # Divisors that bring the privileged state to order 1 (set by build_network).
        self.register_buffer("privileged_scale", torch.ones(config.privileged_size), persistent=False)
        critic_inputs = config.hidden
        self.critic_state = None
        if config.asymmetric_critic:
            self.critic_state = nn.Sequential(
                nn.Linear(config.privileged_size, 128), nn.Tanh(), nn.Linear(128, 128), nn.Tanh()
            )
            critic_inputs += 128
        self.value = nn.Linear(critic_inputs, 1)
        self.aux_frame = self.aux_memory = None
        if config.aux_heads:
            frames = config.obs_shape[0] if config.encoder == "conv" else 1
            shown = frame_visible(config.privileged_size, config.state_layout, frames)
            self.register_buffer("frame_index", torch.tensor(shown), persistent=False)
            self.aux_frame = nn.Linear(config.features, len(self.frame_index))
            self.aux_memory = nn.Linear(config.hidden, config.privileged_size)
        self._init_weights()

    def _init_weights(self) -> None:
        # Small policy logits start the policy near uniform (maximum entropy), as in the A3C
        # reference implementations; LSTM biases zero.
        nn.init.normal_(self.policy.weight, std=0.01)
        nn.init.zeros_(self.policy.bias)
        nn.init.normal_(self.value.weight, std=1.0 / np.sqrt(self.value.in_features))
        nn.init.zeros_(self.value.bias)
        nn.init.zeros_(self.lstm.bias_ih)
        nn.init.zeros_(self.lstm.bias_hh)

    def initial_state(self, batch: int) -> LSTMState:
        zeros = torch.zeros(batch, self.config.hidden)
        return LSTMState(zeros, zeros.clone())

    def side_inputs(
        self, prev_action: torch.Tensor, prev_reward: torch.Tensor, tilt: torch.Tensor | None
    ) -> torch.Tensor:
        """(…,) previous actions (NO_ACTION allowed; a continuous network's: (…, 2), zeros at an
        episode's first step), (…,) previous rewards, (…, 2) tilts in units of the maximum tilt →
        (…, side_size)."""
        parts = [self.action_head.encode(prev_action), prev_reward.float().unsqueeze(-1)]
        if self.config.tilt_input:
            if tilt is None:
                raise ValueError("this network takes the board tilt as input (tilt_input=True); pass tilt")
            parts.append(tilt.float())
        return torch.cat(parts, dim=-1)

    def distribution(self, output: torch.Tensor, temperature: float = 1.0) -> ActionDistribution:
        """π(·|s) from the policy head's output (…, A) (:meth:`step`'s, or :attr:`Unrolled.logits`),
        tempered by ``temperature`` (:meth:`~bimgame.learn.policy_heads.ActionHead.distribution`)."""
        return self.action_head.distribution(output, self.log_std, temperature)

    def critic_parameters(self) -> list[nn.Parameter]:
        """The weights only the value estimate uses: the value head and an asymmetric critic's state MLP."""
        modules = [self.value] + ([self.critic_state] if self.critic_state is not None else [])
        return [p for module in modules for p in module.parameters()]

    def values_of(self, hidden: torch.Tensor, privileged: torch.Tensor | None) -> torch.Tensor:
        """V from the LSTM output (…, H) and, for an asymmetric critic, the privileged state (…, P);
        an asymmetric critic given no privileged state gives NaN (acting needs no value)."""
        if self.critic_state is None:
            return self.value(hidden).squeeze(-1)
        if privileged is None:
            return torch.full(hidden.shape[:-1], float("nan"))
        state = self.critic_state(privileged.float() / self.privileged_scale)
        return self.value(torch.cat([hidden, state], dim=-1)).squeeze(-1)

    def step(
        self,
        obs: torch.Tensor,
        prev_action: torch.Tensor,
        prev_reward: torch.Tensor,
        tilt: torch.Tensor | None,
        state: LSTMState,
        *,
        privileged: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, LSTMState]:
        """One time step for B environments → the policy's output (B, A) (logits; :meth:`distribution`),
        values (B,), next state.
        ``privileged`` (B, P): the state observation an asymmetric critic reads."""
        x = torch.cat([self.encoder(obs), self.side_inputs(prev_action, prev_reward, tilt)], dim=-1)
        h, c = self.lstm(x, state)
        return self.policy(h), self.values_of(h, privileged), LSTMState(h, c)

    def unroll(
        self,
        obs: torch.Tensor,
        prev_action: torch.Tensor,
        prev_reward: torch.Tensor,
        tilt: torch.Tensor | None,
        state: LSTMState,
        starts: torch.Tensor,
        *,
        privileged: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, LSTMState]:
        """A segment of T steps for B environments → the policy's output (T, B, A), values (T, B), final state.

        ``starts`` (T, B) marks the first step of an episode: the LSTM state is zeroed there (the
        previous action and reward inputs should then be NO_ACTION and 0). ``privileged`` (T, B, P):
        the state observations an asymmetric critic reads."""
        out = self.unroll_features(obs, prev_action, prev_reward, tilt, state, starts, privileged=privileged)
        return out.logits, out.values, out.state

    def unroll_features(
        self,
        obs: torch.Tensor,
        prev_action: torch.Tensor,
        prev_reward: torch.Tensor,
        tilt: torch.Tensor | None,
        state: LSTMState,
        starts: torch.Tensor,
        *,
        privileged: torch.Tensor | None = None,
    ) -> Unrolled:
        """:meth:`unroll`, also returning the encoder's and the LSTM's features (for :meth:`aux_loss`)."""
        steps, batch = obs.shape[:2]
        features = self.encoder(obs.reshape(steps * batch, *obs.shape[2:])).reshape(steps, batch, -1)
        x = torch.cat([features, self.side_inputs(prev_action, prev_reward, tilt)], dim=-1)
        hidden, (h, c) = lstm_unroll(self.lstm, x, state, starts)
        return Unrolled(self.policy(hidden), self.values_of(hidden, privileged), LSTMState(h, c), features, hidden)

    def aux_loss(
        self, features: torch.Tensor, hidden: torch.Tensor, privileged: torch.Tensor, mask: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """The auxiliary heads' regression loss: mean squared error, in the privileged state's
        order-1 units, of the frame head (position and channel, from the encoder's features) plus
        the memory head (the whole state, from the LSTM). ``features`` (…, F), ``hidden`` (…, H) and
        ``privileged`` (…, P) line up step by step; ``mask`` (…) selects the steps that count."""
        if self.aux_frame is None or self.aux_memory is None:
            raise ValueError("this network has no auxiliary heads (NetConfig.aux_heads=False)")
        target = privileged.float() / self.privileged_scale
        frame_error = (self.aux_frame(features) - target[..., self.frame_index]).pow(2).mean(-1)
        memory_error = (self.aux_memory(hidden) - target).pow(2).mean(-1)
        if mask is None:
            frame, memory = frame_error.mean(), memory_error.mean()
        else:
            weights = mask.float() / mask.float().sum().clamp(min=1.0)
            frame, memory = (frame_error * weights).sum(), (memory_error * weights).sum()
        return frame + memory, {"aux_frame": frame.item(), "aux_memory": memory.item()}


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
        self.encoder = make_encoder(config)
        extra = 2 if config.tilt_input else 0
        self.head = nn.Sequential(
            nn.Linear(config.features + extra, config.hidden), nn.ReLU(), nn.Linear(config.hidden, 1)
        )

    def forward(self, obs: torch.Tensor, tilt: torch.Tensor | None) -> torch.Tensor:
        """(N, …) observations and (N, 2) tilts in units of the maximum tilt → (N,) values."""
        x = self.encoder(obs)
        if self.config.tilt_input:
            if tilt is None:
                raise ValueError("this value network takes the board tilt as input (tilt_input=True); pass tilt")
            x = torch.cat([x, tilt.float()], dim=-1)
        return self.head(x).squeeze(-1)


#: The networks :func:`_build` makes.
_Network = TypeVar("_Network", RecurrentActorCritic, ValueNetwork)


def _configure_inputs(
    net: RecurrentActorCritic | ValueNetwork,
    config: NetConfig,
    obs_scale: np.ndarray | None,
    background: np.ndarray | None,
    privileged_scale: np.ndarray | None = None,
) -> None:
    """Set the network's fixed inputs: the empty-maze background (conv), the state scale (mlp), the
    privileged state's scale (auxiliary heads, asymmetric critic)."""
    if config.privileged_size:
        if privileged_scale is None or np.shape(privileged_scale) != (config.privileged_size,):
            raise ValueError(
                f"privileged_size {config.privileged_size} needs privileged_scale, that many divisors "
                f"(state_obs_scale(spec)), got {None if privileged_scale is None else np.shape(privileged_scale)}"
            )
        if isinstance(net, RecurrentActorCritic):  # V̂ reads no privileged state
            net.privileged_scale.copy_(torch.as_tensor(np.asarray(privileged_scale, dtype=np.float32)))
    if config.subtract_background:
        if background is None or np.shape(background) != config.obs_shape:
            raise ValueError(
                f"subtract_background needs the empty-maze frame of shape {config.obs_shape} "
                f"(background=maze_background(spec)), got "
                f"{None if background is None else np.shape(background)}"
            )
        if not isinstance(net.encoder, ConvEncoder):
            raise ValueError("subtract_background applies to the conv encoder only")
        net.encoder.background.copy_(torch.as_tensor(np.asarray(background, dtype=np.float32)))
    elif background is not None:
        raise ValueError("background is only used with NetConfig(subtract_background=True)")
    if obs_scale is not None:
        if not isinstance(net.encoder, MLPEncoder):
            raise ValueError("obs_scale applies to the mlp encoder only")
        scale = torch.as_tensor(np.asarray(obs_scale, dtype=np.float32))
        if scale.shape != net.encoder.scale.shape or not torch.all(scale > 0):
            raise ValueError(
                f"obs_scale must be {tuple(net.encoder.scale.shape)} positive numbers, got shape {tuple(scale.shape)}"
            )
        net.encoder.scale.copy_(scale)


def build_value_network(
    config: NetConfig,
    obs_scale: np.ndarray | None = None,
    *,
    seed: int = 0,
    background: np.ndarray | None = None,
    privileged_scale: np.ndarray | None = None,
) -> ValueNetwork:
    """A fresh :class:`ValueNetwork`; arguments as :func:`build_network` (V̂ has no auxiliary heads
    nor privileged critic: the privileged settings are ignored)."""
    return _build(ValueNetwork, config, obs_scale, seed, background, privileged_scale)


def build_network(
    config: NetConfig,
    obs_scale: np.ndarray | None = None,
    *,
    seed: int = 0,
    background: np.ndarray | None = None,
    privileged_scale: np.ndarray | None = None,
) -> RecurrentActorCritic:
    """A fresh network with initial weights drawn from ``seed`` (the global torch generator is
    left untouched); ``obs_scale`` sets the MLP encoder's input divisors (see
    :func:`state_obs_scale`); ``background`` is the empty-maze frame a ``subtract_background``
    network subtracts (see :func:`maze_background`); ``privileged_scale`` the privileged state's
    divisors (:func:`state_obs_scale`) when ``config.privileged_size`` > 0."""
    return _build(RecurrentActorCritic, config, obs_scale, seed, background, privileged_scale)


def _build(
    cls: type[_Network],
    config: NetConfig,
    obs_scale: np.ndarray | None,
    seed: int,
    background: np.ndarray | None,
    privileged_scale: np.ndarray | None = None,
) -> _Network:
    """``cls(config)`` with initial weights drawn from ``seed`` (the global torch generator is left
    untouched), then the fixed inputs set."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = cls(config)
    _configure_inputs(net, config, obs_scale, background, privileged_scale)
    return net


def maze_background(spec: MazeSpec, size: int = 84) -> np.ndarray:
    """The observation frame without a marble, (1, size, size) uint8."""
    return MazeRenderer(spec, size).gray(np.zeros((0, 2)))[None]
