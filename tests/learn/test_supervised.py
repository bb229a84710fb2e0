"""Supervised learning on whole episodes: the loss is −log π of the expert's action for either kind
of action, and behaviour cloning of continuous actions learns a state-dependent expert."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from bimgame.envs.puzzles import puzzle
from bimgame.expert.episode import Episode
from bimgame.learn.dagger import DAggerConfig
from bimgame.learn.supervised import PretrainConfig, padded_batch, policy_epoch, policy_loss_terms, train_policy_epochs

LABYRINTH = "LABYRINTH-EASY"
SPEC = puzzle(LABYRINTH).spec


def _expert(obs: np.ndarray) -> np.ndarray:
    """A state-dependent continuous expert: tilt changes against the first two observed values."""
    return np.clip(-2.0 * obs[:, :2], -1.0, 1.0).astype(np.float32)


def _continuous_episodes(count: int, steps: int, seed: int) -> list[Episode]:
    rng = np.random.default_rng(seed)
    episodes = []
    for index in range(count):
        obs = rng.normal(scale=0.4, size=(steps, 17)).astype(np.float32)
        episodes.append(Episode.from_steps(obs=obs, actions=_expert(obs), rewards=rng.normal(size=steps) * 0.01,
                                           tilt=rng.normal(scale=0.02, size=(steps, 2)), gamma=0.99, id=index))
    return episodes


def _config(**values) -> PretrainConfig:
    defaults = dict(task=LABYRINTH, obs="state", action_type="continuous", hidden=32, features=32, lr=3e-3,
                    bptt=20, batch_episodes=8, eval_episodes=0, aux_heads=False, asymmetric_critic=False)
    return PretrainConfig(**{**defaults, **values})


def test_padded_continuous_batches_keep_the_action_pairs_and_zero_previous_actions():
    episodes = _continuous_episodes(2, 5, seed=0)[:1] + _continuous_episodes(1, 3, seed=1)
    batch = padded_batch(episodes, SPEC.max_tilt)
    assert batch["actions"].shape == (5, 2, 2) and batch["actions"].dtype == torch.float32
    assert batch["prev_action"].shape == (5, 2, 2)
    torch.testing.assert_close(batch["actions"][:3, 1], torch.as_tensor(episodes[1].actions))
    assert torch.all(batch["prev_action"][0] == 0) and torch.all(batch["actions"][3:, 1] == 0)
    assert batch["mask"][:, 1].tolist() == [True, True, True, False, False]


def test_the_discrete_loss_is_the_cross_entropy_of_the_experts_actions():
    config = PretrainConfig(task="STG1", obs="state", hidden=16, features=16, bptt=100, eval_episodes=0)
    net = config.build_policy(0)
    rng = np.random.default_rng(0)
    steps = 6
    episode = Episode.from_steps(obs=rng.normal(size=(steps, 7)).astype(np.float32),
                                 actions=rng.integers(5, size=steps), rewards=np.zeros(steps),
                                 tilt=np.zeros((steps, 2)), gamma=0.99)
    batch = padded_batch([episode], 1.0)
    totals = policy_loss_terms(net, batch, config)
    with torch.no_grad():
        out = net.unroll_features(batch["obs"], batch["prev_action"], batch["prev_reward"], batch["tilt"],
                                  net.initial_state(1), torch.eye(steps, 1, dtype=torch.bool))
        expected = F.cross_entropy(out.logits.reshape(steps, 5), batch["actions"].reshape(-1), reduction="sum")
    assert totals["ce"] == pytest.approx(float(expected), rel=1e-5)
    assert totals["count"] == steps


def test_behaviour_cloning_learns_a_continuous_state_dependent_expert():
    config = _config()
    net = config.build_policy(0, SPEC)
    train, held_out = _continuous_episodes(24, 40, seed=2), _continuous_episodes(6, 40, seed=3)
    before = policy_epoch(net, [padded_batch(held_out, SPEC.max_tilt)], config, None)
    log_std_before = net.log_std.detach().clone()
    train_policy_epochs(net, train, config, 40, np.random.default_rng(0), SPEC.max_tilt)
    after = policy_epoch(net, [padded_batch(held_out, SPEC.max_tilt)], config, None)
    # Greedy actions within 0.25 of the expert's on both axes, on episodes never trained on.
    assert before["accuracy"] < 0.4, before
    assert after["accuracy"] > 0.8, after
    assert after["loss"] < before["loss"] - 1.0
    assert torch.all(net.log_std.detach() < log_std_before)  # the expert is deterministic: π sharpens


def test_pretraining_settings_take_labyrinth_tasks_and_continuous_actions_dagger_on_the_labyrinth_only():
    assert _config().time_limit == puzzle(LABYRINTH).time_limit
    with pytest.raises(ValueError, match=r"PretrainConfig\.task"):
        _config(task="LABYRINTH-IMPOSSIBLE")
    # DAgger's learner on the labyrinth takes either kind of action (its expert labels both) ...
    for action_type in ("discrete", "continuous"):
        assert DAggerConfig(learner=_config(action_type=action_type, aux_heads=False)).learner.task == LABYRINTH
    # ... and on the maze discrete ones only, the maze expert's.
    with pytest.raises(ValueError, match="DAgger supports action_type 'discrete' only"):
        DAggerConfig(learner=PretrainConfig(task="STG1", action_type="continuous", aux_heads=False,
                                            asymmetric_critic=False))
