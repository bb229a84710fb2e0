"""What a policy network's actions are: the discrete set of the paper or the env's continuous tilt
changes, and the action distribution of each.

A recurrent actor-critic (:class:`~bimgame.learn.nets.RecurrentActorCritic`) has one
:class:`ActionHead`, chosen once from its ``action_type`` (:func:`action_head`). Everything that
depends on the kind of action goes through it, so that acting, rollouts and the learners' losses never
ask which kind they have:

- the width of the policy head's output, and the distribution it parameterises
  (:class:`ActionDistribution`: ``sample``, ``greedy``, ``log_prob``, ``entropy``);
- the previous action fed back to the LSTM, and what stands for "no previous action" at an
  episode's first step;
- the action the env executes.

``discrete``: the env's 5 actions (no-op, ±1 tilt step about x, ±1 about y); the head outputs logits
of a :class:`Categorical`, the previous action is fed back one-hot, and
:data:`~bimgame.envs.env.NO_ACTION` (all zeros one-hot) marks an episode's first step.

``continuous``: the env's ``Box(-1, 1, (2,))``, the tilt change about x and y in units of the tilt
step; the head outputs the mean of a :class:`DiagonalGaussian` whose log standard deviation is one
learned parameter per action dimension, independent of the state (as in PPO's continuous-control
setups: Schulman et al. 2017; CleanRL's ``ppo_continuous_action.py``; Stable-Baselines3). A sampled
action is executed clipped to [-1, 1], while its log-probability (what PPO's ratio is taken of) is
that of the unclipped sample, as CleanRL and Stable-Baselines3 do: the clipping belongs to the env,
not to the policy. The previous action fed back is the executed (clipped) 2-vector, zeros at an
episode's first step; the zeroed LSTM state marks that step (as a no-op and a first step give the same
vector).
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Protocol

import torch
from torch import nn

from bimgame.envs.env import ACTION_TYPES, NO_ACTION

__all__ = [
    "ACTION_TYPES",
    "CONTINUOUS_ACTION_SIZE",
    "LOG_STD_INIT",
    "ActionDistribution",
    "Categorical",
    "DiagonalGaussian",
    "ActionHead",
    "DiscreteActions",
    "ContinuousActions",
    "action_head",
    "categorical_kl",
    "check_action_type",
    "require_discrete",
]

#: Numbers in a continuous action: the tilt change about the board's x and y axes.
CONTINUOUS_ACTION_SIZE = 2
#: The Gaussian policy's initial log standard deviation. −0.5 (σ ≈ 0.61) rather than CleanRL's 0 (σ = 1):
#: the initial exploration then matches the discrete network's near-uniform start (per axis, ±1 step
#: with probability 1/5 each: variance 0.4; σ² ≈ 0.37), and about 10 % of the samples fall outside
#: [-1, 1] and are clipped, against 32 % with σ = 1 (whose clipped actions pile up at full steps).
LOG_STD_INIT = -0.5
_LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)


class ActionDistribution(Protocol):
    """π(·|s) for a batch of states (any leading shape ``…``)."""

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        """Actions drawn from π, every random number from ``generator`` (None: torch's global one)."""
        ...

    def greedy(self) -> torch.Tensor:
        """The most likely action: the argmax, or the Gaussian's mean."""
        ...

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        """log π(a|s), shape (…,)."""
        ...

    def entropy(self) -> torch.Tensor:
        """H(π(·|s)), shape (…,)."""
        ...


class Categorical:
    """π over discrete actions from logits (…, A). Its log-probabilities are computed once and shared
    by :meth:`log_prob` and :meth:`entropy` (one log-softmax in a loss's graph)."""

    def __init__(self, logits: torch.Tensor):
        self.logits = logits

    @cached_property
    def log_probs(self) -> torch.Tensor:
        """(…, A) log π(a|s) of every action."""
        return torch.log_softmax(self.logits, dim=-1)

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        probs = torch.softmax(self.logits, dim=-1).reshape(-1, self.logits.shape[-1])
        return torch.multinomial(probs, 1, generator=generator).reshape(self.logits.shape[:-1])

    def greedy(self) -> torch.Tensor:
        return self.logits.argmax(dim=-1)

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        return self.log_probs.gather(-1, actions.long().unsqueeze(-1)).squeeze(-1)

    def entropy(self) -> torch.Tensor:
        return -(self.log_probs.exp() * self.log_probs).sum(-1)


class DiagonalGaussian:
    """π = N(mean, diag(exp(log_std)²)) over continuous actions: ``mean`` (…, D), ``log_std`` (D,)
    or broadcastable to ``mean``."""

    def __init__(self, mean: torch.Tensor, log_std: torch.Tensor):
        self.mean = mean
        self.log_std = log_std.expand_as(mean)

    def sample(self, generator: torch.Generator | None) -> torch.Tensor:
        noise = torch.randn(self.mean.shape, generator=generator, dtype=self.mean.dtype)
        return self.mean + self.log_std.exp() * noise

    def greedy(self) -> torch.Tensor:
        return self.mean

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        z = (actions - self.mean) * torch.exp(-self.log_std)
        return (-0.5 * z.pow(2) - self.log_std - _LOG_SQRT_2PI).sum(-1)

    def entropy(self) -> torch.Tensor:
        return (0.5 + _LOG_SQRT_2PI + self.log_std).sum(-1)


class ActionHead(Protocol):
    """What a network's actions are (see the module notes)."""

    action_type: str
    output_size: int
    """Outputs of the policy head: logits or the Gaussian's mean."""
    input_size: int
    """Width of the previous action fed back to the LSTM."""
    action_shape: tuple[int, ...]
    """Shape of one action tensor per environment: () discrete, (2,) continuous."""

    def no_action(self, batch: int) -> torch.Tensor:
        """The previous action of ``batch`` environments at an episode's first step."""
        ...

    def encode(self, prev_action: torch.Tensor) -> torch.Tensor:
        """Previous actions (…, *action_shape) → the LSTM's input (…, input_size), float32."""
        ...

    def executed(self, actions: torch.Tensor) -> torch.Tensor:
        """What the env executes of the policy's actions (and the next step's previous action)."""
        ...

    def distribution(
        self, output: torch.Tensor, log_std: torch.Tensor | None, temperature: float = 1.0
    ) -> ActionDistribution:
        """π from the policy head's output (…, output_size) and, continuous, the learned log std; at a
        ``temperature`` other than 1, π tempered as :meth:`frozen` tempers a teacher (the logits
        divided by it, or the standard deviation times it: below 1 a sharper π, the same greedy action)."""
        ...

    def frozen(self, output: torch.Tensor, log_std: torch.Tensor | None, temperature: float) -> torch.Tensor:
        """A teacher's π as one tensor (…, P) that :meth:`kl_from` compares a learner with: the
        log-probabilities of the logits divided by ``temperature``, or the Gaussian's mean and log
        standard deviation with the standard deviation times ``temperature`` (below 1: a sharper π)."""
        ...

    def kl_from(self, frozen: torch.Tensor, output: torch.Tensor, log_std: torch.Tensor | None) -> torch.Tensor:
        """KL(teacher ‖ π) per state (…,): the teacher as :meth:`frozen` gives it, π as
        :meth:`distribution` takes it. Zero when π is the teacher (at temperature 1)."""
        ...

    def frozen_log_std(self, frozen: torch.Tensor) -> torch.Tensor:
        """A frozen Gaussian teacher's log standard deviation (…, 2), for a KL that compares means
        only; raises for discrete actions, which have none."""
        ...


class DiscreteActions:
    """The env's ``n`` discrete actions (see the module notes)."""

    action_type = "discrete"
    action_shape: tuple[int, ...] = ()

    def __init__(self, n: int):
        self.output_size = self.input_size = n

    def no_action(self, batch: int) -> torch.Tensor:
        return torch.full((batch,), NO_ACTION, dtype=torch.long)

    def encode(self, prev_action: torch.Tensor) -> torch.Tensor:
        valid = prev_action >= 0
        one_hot = nn.functional.one_hot(prev_action.long().clamp(min=0), self.input_size)
        return (one_hot * valid.unsqueeze(-1)).float()

    def executed(self, actions: torch.Tensor) -> torch.Tensor:
        return actions

    def distribution(
        self, output: torch.Tensor, log_std: torch.Tensor | None, temperature: float = 1.0
    ) -> ActionDistribution:
        return Categorical(output if temperature == 1.0 else output / temperature)

    def frozen(self, output: torch.Tensor, log_std: torch.Tensor | None, temperature: float) -> torch.Tensor:
        return Categorical(output / temperature).log_probs

    def kl_from(self, frozen: torch.Tensor, output: torch.Tensor, log_std: torch.Tensor | None) -> torch.Tensor:
        return categorical_kl(frozen, torch.log_softmax(output, dim=-1))

    def frozen_log_std(self, frozen: torch.Tensor) -> torch.Tensor:
        raise ValueError("a discrete teacher has no standard deviation: a means-only KL needs continuous actions")


class ContinuousActions:
    """The env's continuous tilt changes, 2 numbers in [-1, 1] (see the module notes)."""

    action_type = "continuous"
    output_size = input_size = CONTINUOUS_ACTION_SIZE
    action_shape: tuple[int, ...] = (CONTINUOUS_ACTION_SIZE,)

    def no_action(self, batch: int) -> torch.Tensor:
        return torch.zeros(batch, CONTINUOUS_ACTION_SIZE)

    def encode(self, prev_action: torch.Tensor) -> torch.Tensor:
        if prev_action.shape[-1:] != (CONTINUOUS_ACTION_SIZE,):
            raise ValueError(
                f"a continuous-action network takes previous actions of shape (…, {CONTINUOUS_ACTION_SIZE}), "
                f"got {tuple(prev_action.shape)}"
            )
        return prev_action.float()

    def executed(self, actions: torch.Tensor) -> torch.Tensor:
        return actions.clamp(-1.0, 1.0)

    def distribution(
        self, output: torch.Tensor, log_std: torch.Tensor | None, temperature: float = 1.0
    ) -> ActionDistribution:
        log_std = _required(log_std)
        return DiagonalGaussian(output, log_std if temperature == 1.0 else log_std + math.log(temperature))

    def frozen(self, output: torch.Tensor, log_std: torch.Tensor | None, temperature: float) -> torch.Tensor:
        tempered = DiagonalGaussian(output, _required(log_std) + math.log(temperature))
        return torch.cat([tempered.mean, tempered.log_std], dim=-1)

    def kl_from(self, frozen: torch.Tensor, output: torch.Tensor, log_std: torch.Tensor | None) -> torch.Tensor:
        # Closed form for diagonal Gaussians: Σ_d log(σ/σ_t) + (σ_t² + (μ_t − μ)²) / (2σ²) − ½.
        mean_t, log_std_t = frozen.split(CONTINUOUS_ACTION_SIZE, dim=-1)
        log_std = _required(log_std).expand_as(output)
        ratio = (log_std_t - log_std).exp().pow(2) + ((mean_t - output) * torch.exp(-log_std)).pow(2)
        return (log_std - log_std_t + 0.5 * ratio - 0.5).sum(-1)

    def frozen_log_std(self, frozen: torch.Tensor) -> torch.Tensor:
        return frozen[..., CONTINUOUS_ACTION_SIZE:]


def categorical_kl(teacher_log_probs: torch.Tensor, log_probs: torch.Tensor) -> torch.Tensor:
    """KL(teacher ‖ π) = Σ_a π_t(a) (log π_t(a) − log π(a)) per state (…,), from both
    distributions' log-probabilities (…, A)."""
    return (teacher_log_probs.exp() * (teacher_log_probs - log_probs)).sum(-1)


def _required(log_std: torch.Tensor | None) -> torch.Tensor:
    """A Gaussian policy's log standard deviations, which a continuous network must have."""
    if log_std is None:
        raise ValueError("a Gaussian policy needs its log standard deviation (RecurrentActorCritic.log_std)")
    return log_std


def check_action_type(owner: str, value: object) -> None:
    """Raise ``ValueError`` naming ``owner`` unless ``value`` is one of :data:`ACTION_TYPES`."""
    if value not in ACTION_TYPES:
        raise ValueError(f"{owner}.action_type must be one of {ACTION_TYPES}, got {value!r}")


def action_head(action_type: str, n_actions: int) -> ActionHead:
    """The :class:`ActionHead` of ``action_type`` (``n_actions``: the discrete actions' count)."""
    check_action_type("NetConfig", action_type)
    if action_type == "discrete":
        return DiscreteActions(n_actions)
    return ContinuousActions()


def require_discrete(learner: str, action_type: str, hint: str) -> None:
    """Refuse a continuous-action network for what takes discrete actions only, naming ``learner``,
    the value and the allowed one; ``hint`` says what to use instead."""
    if action_type != "discrete":
        raise ValueError(f"{learner} supports action_type 'discrete' only; got {action_type!r} ({hint})")
