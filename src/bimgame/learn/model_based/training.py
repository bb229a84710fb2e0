"""The model-based learner's loop: explore, fit, plan, refit (Dyna-style model learning as in PETS,
Chua et al. 2018, with a planner instead of a policy).

1. ``explore_steps`` random action steps (:func:`~bimgame.learn.model_based.transitions.explore`);
2. ``iterations`` times: fit the law on every transition so far, play ``episodes_per_iteration``
   episodes with the MPC planning through it, keep their transitions;
3. fit the law once more on everything: the run's law.

Every environment step, exploring or playing, counts towards ``env_steps``: the budget CyberRunner's
≈ 1M real steps compare with.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_mpc import LabyrinthMPCConfig
from bimgame.learn.model_based.agent import ModelBasedAgent, play_episode, playable_env
from bimgame.learn.model_based.marble_law import MarbleLaw
from bimgame.learn.model_based.transitions import Transitions, explore
from bimgame.util.progress import ProgressBar

__all__ = ["ModelBasedSettings", "ModelBasedRun", "learn_model_based"]


@dataclasses.dataclass(frozen=True)
class ModelBasedSettings:
    """How long the learner explores and plays, and how it plans."""

    explore_steps: int = 5000
    """Random action steps before the first fit (5,000 left ≈ 130–300 free transitions on hard)."""
    iterations: int = 4
    """Fit-then-play rounds after exploring."""
    episodes_per_iteration: int = 4
    """Episodes played with each fitted law."""
    max_episode_steps: int = 3000
    """Longest episode played (CyberRunner's 54.5 s at 55 Hz)."""
    free_margin: float = 0.002
    """How far (m) beyond the marble's radius from every wall a transition must stay to be fitted."""
    planner: LabyrinthMPCConfig = dataclasses.field(default_factory=LabyrinthMPCConfig)
    """The MPC's settings (the expert's defaults)."""

    def __post_init__(self) -> None:
        for name in ("explore_steps", "iterations", "episodes_per_iteration", "max_episode_steps"):
            value = getattr(self, name)
            least = 0 if name == "iterations" else 1
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{name} must be an integer ≥ {least}, got {value!r}")
        if not (
            isinstance(self.free_margin, (int, float)) and math.isfinite(self.free_margin) and self.free_margin >= 0
        ):
            raise ValueError(f"free_margin must be a non-negative number (m), got {self.free_margin!r}")
        if not isinstance(self.planner, LabyrinthMPCConfig):
            raise TypeError(f"planner must be a LabyrinthMPCConfig, got {type(self.planner).__name__}")


@dataclasses.dataclass
class ModelBasedRun:
    """A finished run: its final ``law``, the ``env_steps`` it took, and per iteration what the fitted
    law did (``iterations``: env steps before it, free transitions and R² of its fit, its episodes)."""

    law: MarbleLaw
    env_steps: int
    iterations: list[dict[str, Any]]


def learn_model_based(
    layout: str, settings: ModelBasedSettings | None = None, *, seed: int, progress: bool = True, **env_settings: Any
) -> ModelBasedRun:
    """Run the learner on the labyrinth ``layout`` (env settings as :class:`LabyrinthEnv`'s, continuous
    actions and state observations); every draw derives from ``seed``."""
    settings = settings if settings is not None else ModelBasedSettings()
    if not isinstance(settings, ModelBasedSettings):
        raise TypeError(f"settings must be ModelBasedSettings, got {type(settings).__name__}")
    env = LabyrinthEnv(layout, **env_settings)
    try:
        playable_env(env)
    except ValueError:
        env.close()
        raise
    rng = np.random.default_rng([seed, 0])
    transitions = Transitions()
    records: list[dict[str, Any]] = []
    try:
        explore(env, settings.explore_steps, rng, transitions)
        episodes = settings.iterations * settings.episodes_per_iteration
        with ProgressBar(f"model-based on the {layout} labyrinth", episodes, enabled=progress) as bar:
            for iteration in range(settings.iterations):
                law = MarbleLaw.fit(transitions, env.board, free_margin=settings.free_margin)
                agent = ModelBasedAgent.for_env(
                    env, law, settings.planner, rng=np.random.default_rng([seed, 1, iteration])
                )
                record: dict[str, Any] = {
                    "iteration": iteration,
                    "env_steps_before": len(transitions),
                    "free_transitions": law.free_transitions,
                    "fit_r2": [round(float(v), 5) for v in law.r2],
                    "episodes": [],
                }
                for _ in range(settings.episodes_per_iteration):
                    episode = play_episode(
                        env,
                        agent,
                        seed=int(rng.integers(2**31)),
                        max_steps=settings.max_episode_steps,
                        transitions=transitions,
                    )
                    record["episodes"].append(episode)
                    bar.update(advance=1, info=f"{episode['ending']} at {episode['progress_fraction']:.0%}")
                records.append(record)
        law = MarbleLaw.fit(transitions, env.board, free_margin=settings.free_margin)
    finally:
        env.close()
    return ModelBasedRun(law=law, env_steps=len(transitions), iterations=records)
