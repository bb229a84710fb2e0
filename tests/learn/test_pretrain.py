"""Learning from the expert: relabelling episodes for other tasks, pre-training π^s and V̂, and
using them in A3C (``bimgame train --init`` / ``--value-reward``)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.expert.datasets import iterate_sequences
from bimgame.learn.a3c import A3CConfig, network_for
from bimgame.learn.common import run_evaluation as evaluate
from bimgame.learn.actor import RecurrentActor, evaluate_network
from bimgame.learn.checkpoints import load_weights
from bimgame.learn.common import load_run_network, load_value_network
from bimgame.learn.pretrain import load_sequences, pretrain
from bimgame.learn.rewards import RewardSettings, env_wrapper_for
from bimgame.learn.runs import KIND_POLICY, KIND_VALUE
from bimgame.learn.supervised import PretrainConfig, split_episodes
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import MAX_EPISODE_STEPS, Task

GAMMA = 0.9
MAX_TILT = MazeSpec.merl().max_tilt


# ----------------------------------------------------------------------------------- helpers
def _discounted(rewards, gamma) -> np.ndarray:
    """G_t = Σ_k γ^k r_{t+k}, written out."""
    rewards = np.asarray(rewards, dtype=np.float64)
    return np.array([sum(gamma ** k * r for k, r in enumerate(rewards[t:])) for t in range(len(rewards))])


def _random_success_rate(task: str, episodes: int, seed: int) -> float:
    """Uniformly random actions from the start positions evaluate_network(seed=seed) uses."""
    env = BallInMazeVectorEnv(episodes, task=task, obs_mode="state", max_episode_steps=MAX_EPISODE_STEPS[Task(task)],
                              nthread=1, autoreset_mode="same_step")
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    finished, success = np.zeros(episodes, bool), np.zeros(episodes, bool)
    try:
        while not finished.all():
            _, _, terminated, truncated, _ = env.step(rng.integers(5, size=episodes))
            new = (terminated | truncated) & ~finished
            success[new] = terminated[new]
            finished |= terminated | truncated
    finally:
        env.close()
    return float(success.mean())


def _teacher_forced_accuracy(net, sequences: list[dict]) -> float:
    """Share of steps where the greedy action equals the expert's, with the network fed exactly
    as when acting (RecurrentActor), the expert's previous action and reward as inputs."""
    correct = total = 0
    for s in sequences:
        actor = RecurrentActor(net, 1, greedy=True)
        for t in range(len(s)):
            tilt = torch.as_tensor(s.tilt[t:t + 1] / np.float32(MAX_TILT))
            actions, _, _ = actor.act(s.obs[t:t + 1], tilt if net.config.tilt_input else None)
            correct += int(actions.item() == s.actions[t])
            total += 1
            actor.observe(torch.as_tensor(s.actions[t:t + 1]), s.rewards[t:t + 1], np.array([False]))
    return correct / total


def _csv_rows(path) -> list[dict[str, str]]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _split(result) -> tuple[PretrainConfig, list[dict], np.ndarray, np.ndarray]:
    """The run's settings, its relabelled episodes and its (training, held-out) split."""
    stored = json.loads((result.run_dir / "config.json").read_text())
    config = PretrainConfig.from_dict(stored["pretrain"])
    sequences = load_sequences(stored["data"], config.task, config.obs, config.gamma)
    train_idx, val_idx = split_episodes(len(sequences), config.val_fraction, np.random.default_rng(config.seed))
    assert stored["episodes"] == {"train": len(train_idx), "held_out": len(val_idx)}
    return config, sequences, train_idx, val_idx


def test_relabelling_for_the_datasets_own_task_reproduces_its_rewards_and_a_harder_task_is_refused(
        stg1_dataset, tmp_path):
    recorded = list(iterate_sequences(stg1_dataset, obs="state", gamma=0.99))
    relabelled = load_sequences(stg1_dataset, "STG1", "state", 0.99)
    assert len(relabelled) == len(recorded) > 0
    for mine, env in zip(relabelled, recorded):
        np.testing.assert_array_equal(mine.rewards, env.rewards)
        np.testing.assert_allclose(mine.returns, env.returns, rtol=1e-6)
        assert (mine.terminated, mine.truncated) == (env.terminated, env.truncated)

    for harder in ("FULL", "STG2"):
        with pytest.raises(ValueError, match=rf"STG1 episodes.*{harder}"):
            load_sequences(stg1_dataset, harder, "state", 0.99)
    out = tmp_path / "refused"
    with pytest.raises(ValueError, match="STG1.*FULL"):
        pretrain(PretrainConfig(task="FULL", obs="state"), stg1_dataset, out, progress=False)
    assert not out.exists()


# ------------------------------------------------------------------------------ pre-training
def test_pretrained_policy_predicts_the_expert_and_beats_a_random_policy(pretrained_stg1, one_torch_thread):
    result = pretrained_stg1
    stored = json.loads((result.run_dir / "config.json").read_text())
    summary = json.loads((result.run_dir / "summary.json").read_text())
    assert stored["kind"] == summary["kind"] == KIND_POLICY
    config, sequences, _, val_idx = _split(result)

    # Well above chance (1 in 5 actions) on episodes it never trained on.
    assert summary["val_accuracy"] == pytest.approx(result.val_accuracy)
    assert result.val_accuracy >= 0.25

    # Early stopping kept the best epoch's weights, not the last ones.
    rows = _csv_rows(result.run_dir / "pretrain.csv")
    epochs = [r for r in rows if int(r["step"]) >= 1]
    assert len(epochs) == result.epochs_run == summary["epochs_run"]
    assert result.epochs_run == min(config.epochs, result.best_epoch + config.patience)
    assert 1 <= result.best_epoch < result.epochs_run
    losses = [float(r["val_loss"]) for r in epochs]
    assert int(epochs[int(np.argmin(losses))]["step"]) == result.best_epoch == summary["best_epoch"]
    best_row = epochs[result.best_epoch - 1]
    assert float(best_row["val_accuracy"]) == pytest.approx(result.val_accuracy, rel=1e-5)
    assert float(epochs[-1]["val_accuracy"]) != pytest.approx(result.val_accuracy, rel=1e-5)
    # ... and the stored weights reproduce the best epoch's held-out accuracy when acting.
    net, run, step = load_run_network(result.run_dir)
    assert (run.task, run.network.obs, step) == ("STG1", "state", 0)
    assert _teacher_forced_accuracy(net, [sequences[i] for i in val_idx]) == pytest.approx(result.val_accuracy)

    # As a policy: greedy π^s against uniformly random actions from the same 40 start positions.
    episodes, seed = 40, 2024
    greedy = evaluate_network(net, task="STG1", obs_mode="state", episodes=episodes, seed=seed, greedy=True)
    random_rate = _random_success_rate("STG1", episodes, seed)
    assert greedy.success_rate >= random_rate + 0.2, (greedy.success_rate, random_rate)
    assert result.policy_eval["episodes"] == episodes
    assert result.policy_eval["greedy_success_rate"] >= random_rate + 0.2
    assert summary["policy_eval"] == pytest.approx(result.policy_eval)


def test_value_network_beats_predicting_the_mean_return_and_is_frozen(value_stg1, pretrained_stg1,
                                                                      one_torch_thread):
    result = value_stg1
    summary = json.loads((result.run_dir / "summary.json").read_text())
    assert summary["kind"] == KIND_VALUE and result.policy_eval is None and np.isnan(result.val_accuracy)
    config, sequences, train_idx, val_idx = _split(result)
    train_returns = np.concatenate([sequences[i].returns for i in train_idx]).astype(np.float64)
    val_returns = np.concatenate([sequences[i].returns for i in val_idx]).astype(np.float64)
    mean_rmse = float(np.sqrt(np.mean((val_returns - train_returns.mean()) ** 2)))
    assert result.val_value_rmse < 0.8 * mean_rmse, (result.val_value_rmse, mean_rmse)

    net, run = load_value_network(result.run_dir)
    assert PretrainConfig.from_dict(run.config["pretrain"]) == config
    assert not net.training
    assert all(not p.requires_grad for p in net.parameters())
    # The stored weights are the best epoch's: they reproduce its held-out RMSE.
    obs = torch.as_tensor(np.concatenate([sequences[i].obs for i in val_idx]))
    tilt = torch.as_tensor(np.concatenate([sequences[i].tilt for i in val_idx]) / np.float32(MAX_TILT))
    values = net(obs, tilt)
    assert not values.requires_grad  # frozen: nothing to backpropagate into
    rmse = float(np.sqrt(np.mean((values.numpy().astype(np.float64) - val_returns) ** 2)))
    assert rmse == pytest.approx(result.val_value_rmse, rel=1e-5)

    with pytest.raises(ValueError, match="--value-only"):
        load_value_network(pretrained_stg1.run_dir)


# ------------------------------------------------------------------------------ in A3C
INIT_STEPS = 6_000
SHAPING_COEF = 5.0


@pytest.fixture(scope="module")
def shaped_run_from_pretrained(pretrained_stg1, value_stg1, tmp_path_factory):
    """A short A3C run started from π^s, with the reward shaped by V̂ and geodesic progress."""
    run_dir = tmp_path_factory.mktemp("a3c") / "run"
    code = main(["train", "--run-dir", str(run_dir), "--task", "STG1", "--init", str(pretrained_stg1.run_dir),
                 "--value-reward", str(value_stg1.run_dir), "--geodesic-reward", str(SHAPING_COEF),
                 "--steps", str(INIT_STEPS), "--workers", "1", "--eval-every", "10k", "--eval-episodes", "10",
                 "--no-progress"])
    return code, run_dir


def test_train_init_starts_from_the_pretrained_weights(shaped_run_from_pretrained, pretrained_stg1, one_torch_thread):
    code, run_dir = shaped_run_from_pretrained
    assert code == 0
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["init"] == str(pretrained_stg1.run_dir)
    config = A3CConfig.from_dict(stored["a3c"])
    pretrained = json.loads((pretrained_stg1.run_dir / "config.json").read_text())["network"]
    # The network settings come from the pre-trained run.
    for key in ("obs", "hidden", "features", "tilt_input"):
        assert getattr(config.network, key) == pretrained[key]
    assert config.schedule.eval_episodes == 10

    first = _csv_rows(run_dir / "eval.csv")[0]
    assert int(first["step"]) == 0
    net = network_for(config)
    load_weights(net, pretrained_stg1.run_dir / "checkpoint.pt")
    expected = evaluate(net, config)
    assert {k: first[k] for k in expected} == {k: f"{v:.6g}" for k, v in expected.items()}
    # A network that did not start from π^s would score differently on these episodes.
    fresh = evaluate(network_for(config), config)
    assert {k: f"{v:.6g}" for k, v in fresh.items()} != {k: first[k] for k in fresh}


def test_shaped_training_logs_the_task_reward_and_resume_keeps_the_shaping(
        shaped_run_from_pretrained, value_stg1, tmp_path, capsys, one_torch_thread):
    code, run_dir = shaped_run_from_pretrained
    assert code == 0
    stored = json.loads((run_dir / "config.json").read_text())
    reward = {"value_reward": str(value_stg1.run_dir), "geodesic_coef": SHAPING_COEF}
    assert stored["reward"] == reward

    def episodes_after(step: int) -> list[dict[str, str]]:
        return [r for r in _csv_rows(run_dir / "episodes.csv") if int(r["step"]) > step]

    # Learning curves show STG1's own reward: 1 for a success, else 0 (shaped returns are fractional).
    episodes = episodes_after(-1)
    assert len(episodes) >= 10 and any(r["success"] == "True" for r in episodes)
    for row in episodes:
        assert float(row["return"]) == (1.0 if row["success"] == "True" else 0.0), row

    # The recorded settings build the shaping the workers used: r + 5·(d − d') + γ·V̂(s') − V̂(s).
    config = A3CConfig.from_dict(stored["a3c"])
    vhat, _ = load_value_network(value_stg1.run_dir)
    env = env_wrapper_for(RewardSettings(**stored["reward"]), obs=config.network.obs,
                          gamma=config.optimization.gamma)(
        BallInMazeVectorEnv(4, task="STG1", obs_mode="state", max_episode_steps=300, nthread=1,
                            autoreset_mode="same_step"))

    def potential(obs, info) -> np.ndarray:
        tilt = torch.as_tensor(np.asarray(info["tilt"], np.float32) / np.float32(MAX_TILT))
        return vhat(torch.as_tensor(obs), tilt).numpy().astype(np.float64)

    obs, info = env.reset(seed=3)
    phi, distance = potential(obs, info), info["geodesic_distance"].sum(axis=-1)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, r, terminated, truncated, info = env.step(rng.integers(5, size=4))
        assert not (terminated | truncated).any()
        phi_next, distance_next = potential(obs, info), info["geodesic_distance"].sum(axis=-1)
        expected = SHAPING_COEF * (distance - distance_next) + config.optimization.gamma * phi_next - phi
        np.testing.assert_allclose(info["shaping"], expected, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(r, info["task_reward"] + info["shaping"])
        assert np.all(np.abs(info["shaping"]) > 0)
        phi, distance = phi_next, distance_next
    env.close()

    # A resume may not change the reward, and keeps it when none is given.
    capsys.readouterr()
    assert main(["train", "--run-dir", str(run_dir), "--resume", "--steps", "8k", "--geodesic-reward", "3",
                 "--no-progress"]) == 2
    assert "--resume must keep the run's reward" in capsys.readouterr().err
    last_step = max(int(r["step"]) for r in episodes)
    assert main(["train", "--run-dir", str(run_dir), "--resume", "--steps", "8k", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"value_reward={value_stg1.run_dir}" in err and f"geodesic_coef={SHAPING_COEF}" in err
    assert json.loads((run_dir / "config.json").read_text())["reward"] == reward
    resumed = episodes_after(last_step)
    assert resumed
    for row in resumed:
        assert float(row["return"]) == (1.0 if row["success"] == "True" else 0.0), row


# ------------------------------------------------------------------------------ CLI errors
def test_command_line_errors_exit_2_and_create_nothing(stg1_dataset, pretrained_stg1, value_stg1, tmp_path, capsys):
    capsys.readouterr()
    run = tmp_path / "run"
    common = ["--run-dir", str(run), "--task", "STG1", "--steps", "1k", "--workers", "1", "--no-progress"]

    # A value function is not a policy to start from.
    assert main(["train", *common, "--init", str(value_stg1.run_dir)]) == 2
    assert "--value-reward" in capsys.readouterr().err
    # V̂ saw state observations; a pixel agent cannot use it.
    assert main(["train", *common, "--obs", "pixels", "--value-reward", str(value_stg1.run_dir)]) == 2
    err = capsys.readouterr().err
    assert "--value-reward" in err and "state" in err and "pixels" in err
    assert not run.exists()

    # The STG1 dataset cannot label FULL episodes.
    out = tmp_path / "pre"
    pretrain_args = ["pretrain", "--data", str(stg1_dataset), "--out", str(out), "--obs", "state", "--no-progress"]
    assert main([*pretrain_args, "--task", "FULL"]) == 2
    err = capsys.readouterr().err
    assert "STG1" in err and "FULL" in err
    assert not out.exists()

    # An existing run is never overwritten.
    existing = pretrained_stg1.run_dir
    before = {p.name: p.read_bytes() for p in existing.iterdir() if p.is_file()}
    assert main(["pretrain", "--data", str(stg1_dataset), "--out", str(existing), "--task", "STG1", "--obs", "state",
                 "--epochs", "1", "--eval-episodes", "0", "--no-progress"]) == 2
    assert "already holds a run" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in existing.iterdir() if p.is_file()} == before
