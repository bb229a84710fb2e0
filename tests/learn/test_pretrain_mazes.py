"""Pre-training on an expert dataset of many mazes (``bimgame generate --num-mazes``): the network reads
the maze encoding, its held-out accuracy and its evaluation on the dataset's mazes, and π^s starting
PPO and A3C on those mazes — with clear refusals when the network and the run do not fit."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import bimgame.learn.pretrain as pretraining
from bimgame.envs.mazes import MAZE_ENCODING_ANGLES
from bimgame.expert.datasets import generate_dataset
from bimgame.expert.mpc import MPCConfig
from bimgame.learn.a3c import A3CConfig, resolve_config, train
from bimgame.learn.actor import RecurrentActor
from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.common import load_run_network
from bimgame.learn.init_network import check_init_network
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.learn.ppo.training import resolve_ppo_config
from bimgame.learn.pretrain import load_sequences, pretrain
from bimgame.learn.runs import torch_threads
from bimgame.learn.supervised import PretrainConfig, split_episodes
from bimgame.sim.maze import MazeSpec

ENCODED = 7 + 4 * MAZE_ENCODING_ANGLES
NETWORK = dict(task="STG1", obs="state", hidden=16, features=16)
PPO_TINY = dict(
    **NETWORK, envs_per_worker=4, n_steps=16, minibatches=2, eval_every=0, eval_episodes=2, log_every=64, steps=64
)
MAZES = {"num_mazes": 3, "start_maze": 4}


@pytest.fixture(scope="module")
def maze_data(tmp_path_factory):
    """6 STG1 expert episodes (a cheaper expert than the default) on training mazes 4, 5 and 6."""
    out = tmp_path_factory.mktemp("maze-data") / "data"
    config = MPCConfig(n_samples=6, horizon=10)
    return generate_dataset(out, "STG1", 6, seed=3, config=config, max_steps=60, workers=1, progress=False, **MAZES)


@pytest.fixture(scope="module")
def pi_s(maze_data, tmp_path_factory):
    """π^s pre-trained on :func:`maze_data` (a small network, a few epochs, evaluated over 4 episodes)."""
    config = PretrainConfig(**NETWORK, epochs=4, patience=2, eval_episodes=4, seed=0)
    with torch_threads(1):
        return pretrain(config, maze_data, tmp_path_factory.mktemp("pi-s") / "policy", progress=False)


@pytest.fixture(scope="module")
def merl_pi_s(tmp_path_factory):
    """π^s of MERL's maze alone (a two-episode dataset, one epoch): a network without the encoding."""
    root = tmp_path_factory.mktemp("merl")
    data = generate_dataset(
        root / "data",
        "STG1",
        2,
        seed=0,
        config=MPCConfig(n_samples=4, horizon=8),
        max_steps=20,
        workers=1,
        progress=False,
    )
    config = PretrainConfig(**NETWORK, epochs=1, eval_episodes=0)
    with torch_threads(1):
        return pretrain(config, data, root / "policy", progress=False).run_dir


def _acting_accuracy(net, sequences) -> float:
    """Share of steps where the greedy action is the expert's, the network fed as when acting."""
    max_tilt = np.float32(MazeSpec.merl().max_tilt)
    correct = total = 0
    for s in sequences:
        actor = RecurrentActor(net, 1, greedy=True)
        for t in range(len(s)):
            actions, _, _ = actor.act(s.obs[t : t + 1], torch.as_tensor(s.tilt[t : t + 1] / max_tilt))
            correct += int(actions.item() == s.actions[t])
            total += 1
            actor.observe(torch.as_tensor(s.actions[t : t + 1]), s.rewards[t : t + 1], np.array([False]))
    return correct / total


def test_pretraining_on_mazes_reads_the_encoding_and_measures_held_out_accuracy(maze_data, pi_s, one_torch_thread):
    stored = json.loads((pi_s.run_dir / "config.json").read_text())
    assert (stored["num_mazes"], stored["start_maze"]) == (3, 4) and pi_s.mazes == MAZES
    assert stored["network"]["maze_encoding"] and stored["pretrain"]["maze_encoding"]
    net, run, _ = load_run_network(pi_s.run_dir)
    assert net.config.obs_shape == (ENCODED,) and run.network.maze_encoding
    assert torch.allclose(net.encoder.scale[7:], torch.tensor(float(np.sqrt(ENCODED - 7))))

    # The held-out accuracy is the kept weights' on episodes it never trained on, as when acting.
    config = PretrainConfig.from_dict(stored["pretrain"])
    sequences = load_sequences(maze_data, "STG1", "state", config.gamma)
    assert all(s.obs.shape[1] == ENCODED for s in sequences)
    _, held_out = split_episodes(len(sequences), config.val_fraction, np.random.default_rng(config.seed))
    assert stored["episodes"]["held_out"] == len(held_out) >= 1
    assert 0.0 <= pi_s.val_accuracy <= 1.0
    assert _acting_accuracy(net, [sequences[i] for i in held_out]) == pytest.approx(pi_s.val_accuracy)
    summary = json.loads((pi_s.run_dir / "summary.json").read_text())
    assert summary["val_accuracy"] == pytest.approx(pi_s.val_accuracy)
    assert pi_s.policy_eval is not None and pi_s.policy_eval["episodes"] == 4


def test_pi_s_alone_is_evaluated_on_the_datasets_mazes(maze_data, tmp_path, monkeypatch, one_torch_thread):
    calls = []
    real = pretraining.evaluate_greedy_and_sampled

    def recording(net, **kwargs):
        calls.append(kwargs)
        return real(net, **kwargs)

    monkeypatch.setattr(pretraining, "evaluate_greedy_and_sampled", recording)
    result = pretrain(PretrainConfig(**NETWORK, epochs=1, eval_episodes=2), maze_data, tmp_path / "run", progress=False)
    assert [call["mazes"] for call in calls] == [MAZES]
    assert result.policy_eval is not None and result.policy_eval["episodes"] == 2


def test_maze_encoding_on_a_dataset_of_merls_maze_is_refused(merl_pi_s, tmp_path):
    stored = json.loads((merl_pi_s / "config.json").read_text())
    assert not stored["network"]["maze_encoding"] and "num_mazes" not in stored
    out = tmp_path / "refused"
    with pytest.raises(ValueError, match=r"maze_encoding: the dataset in .* was generated on MERL's maze alone"):
        pretrain(PretrainConfig(**NETWORK, maze_encoding=True), stored["data"], out, progress=False)
    assert not out.exists()


def test_pi_s_starts_ppo_on_the_datasets_mazes(pi_s, tmp_path, one_torch_thread):
    config = PPOConfig.from_flat(PPO_TINY, **MAZES, kl_coef=0.01)
    assert config.network.maze_encoding
    result = train_ppo(config, tmp_path / "run", init=pi_s.run_dir, progress=False)
    assert result.stopped == "finished"
    # The run started from π^s: the frozen teacher it keeps is π^s's weights.
    teacher = load_checkpoint(tmp_path / "run" / "teacher.pt")["model"]
    weights = load_checkpoint(pi_s.run_dir)["model"]
    assert teacher.keys() == weights.keys()
    assert all(torch.equal(teacher[k], weights[k]) for k in weights)
    net, run, _ = load_run_network(tmp_path / "run")
    assert net.config.obs_shape == (ENCODED,) and run.network.maze_encoding

    # The command line's way: the network settings are taken from π^s, the mazes given.
    resolved = resolve_ppo_config({"task": "STG1", "steps": 64, **MAZES}, tmp_path / "other", init=pi_s.run_dir)
    assert (resolved.network.hidden, resolved.network.features, resolved.network.maze_encoding) == (16, 16, True)
    a3c = resolve_config({"task": "STG1", "steps": 64, **MAZES}, tmp_path / "a3c", init=pi_s.run_dir)
    assert a3c.network.maze_encoding and a3c.network.hidden == 16
    check_init_network(pi_s.run_dir, a3c.network)  # fits


def test_networks_that_do_not_fit_the_run_are_refused_naming_the_setting(pi_s, merl_pi_s, tmp_path):
    run_dir = tmp_path / "run"
    reads = (
        r"maze_encoding: True there, False here\): it reads the maze encoding .* give this run "
        r"--num-mazes 3 --start-maze 4"
    )
    # A network of many mazes into a run on MERL's maze.
    with pytest.raises(ValueError, match=reads):
        train_ppo(PPOConfig.from_flat(PPO_TINY), run_dir, init=pi_s.run_dir, progress=False)
    with pytest.raises(ValueError, match=reads):
        train(A3CConfig.from_flat(NETWORK, workers=1, steps=64), run_dir, init=pi_s.run_dir, progress=False)
    for resolve in (resolve_ppo_config, resolve_config):
        with pytest.raises(
            ValueError, match=r"does not fit a run on MERL's maze alone: .*--num-mazes 3 --start-maze 4"
        ):
            resolve({"task": "STG1", "steps": 64}, run_dir, init=pi_s.run_dir)

    # A network of MERL's maze into a run on many mazes (whose network reads the encoding).
    lacks = (
        r"maze_encoding: False there, True here\): this run on many mazes .* pre-train on a dataset generated "
        r"with --num-mazes"
    )
    with pytest.raises(ValueError, match=lacks):
        train_ppo(PPOConfig.from_flat(PPO_TINY, **MAZES), run_dir, init=merl_pi_s, progress=False)
    with pytest.raises(ValueError, match=lacks):
        train(A3CConfig.from_flat(NETWORK, workers=1, steps=64, **MAZES), run_dir, init=merl_pi_s, progress=False)
    resolved = resolve_config({"task": "STG1", "steps": 64, **MAZES}, run_dir, init=merl_pi_s)
    with pytest.raises(ValueError, match=lacks):
        check_init_network(merl_pi_s, resolved.network)

    # Any other network setting, by name.
    with pytest.raises(ValueError, match=r"hidden: 16 there, 32 here"):
        train(
            A3CConfig.from_flat(NETWORK, hidden=32, workers=1, steps=64, **MAZES),
            run_dir,
            init=pi_s.run_dir,
            progress=False,
        )
    assert not run_dir.exists()  # every refusal came before the run directory


def test_pretraining_with_gate_bearings_reads_them_from_the_stored_positions(maze_data, tmp_path, one_torch_thread):
    """Datasets store observations without bearings; read with ``gate_bearings`` each step gets the
    bearings an env with ``gate_bearings=True`` would have shown in that episode's maze, and π^s
    pre-trained so reads 7 + 128 + 12 values, is evaluated on bearing envs and starts a PPO run."""
    from bimgame.envs.gate_bearings import GateBearings
    from bimgame.sim.maze_sets import maze_number

    plain = load_sequences(maze_data, "STG1", "state", 0.99)
    with_bearings = load_sequences(maze_data, "STG1", "state", 0.99, gate_bearings=True)
    for a, b in zip(plain, with_bearings, strict=True):
        np.testing.assert_array_equal(b.obs[:, :ENCODED], a.obs)
        assert b.obs.shape[1] == ENCODED + 12
    episode = with_bearings[0]
    first_maze = maze_number(MAZES["start_maze"] + episode.id % MAZES["num_mazes"])
    expected = GateBearings.of(first_maze)(episode.obs[:, 0].astype(float), episode.obs[:, 1].astype(float))
    np.testing.assert_allclose(episode.obs[:, ENCODED:], expected, atol=1e-6)

    result = pretrain(
        PretrainConfig(**NETWORK, epochs=1, eval_episodes=2, gate_bearings=True),
        maze_data,
        tmp_path / "pi",
        progress=False,
    )
    net, run, _ = load_run_network(result.run_dir)
    assert net.config.obs_shape == (ENCODED + 12,) and run.network.gate_bearings
    assert result.policy_eval is not None and result.policy_eval["episodes"] == 2
    config = PPOConfig.from_flat(PPO_TINY, **MAZES, gate_bearings=True)
    assert train_ppo(config, tmp_path / "run", init=result.run_dir, progress=False).stopped == "finished"


def test_gate_bearings_on_a_dataset_of_merls_maze_are_refused(merl_pi_s, tmp_path):
    stored = json.loads((merl_pi_s / "config.json").read_text())
    with pytest.raises(ValueError, match=r"gate_bearings: the dataset in .* was generated on MERL's maze alone"):
        pretrain(PretrainConfig(**NETWORK, gate_bearings=True), stored["data"], tmp_path / "refused", progress=False)
