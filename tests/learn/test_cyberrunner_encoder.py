"""Learners on CyberRunner's own observation of the labyrinth (``obs="cyberrunner"``): the flat form the
env gives them round-trips its ``Dict``, the encoder splits it again and reads both parts, PPO trains,
resumes and evaluates on it, and what does not apply (the maze, the pixel network's extras) is refused
by name."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from bimgame.cli.main import main
from bimgame.envs.labyrinth_cyberrunner import CYBERRUNNER_FLAT_SIZE, flatten_cyberrunner, unflatten_cyberrunner
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.labyrinth_vector import LabyrinthVectorEnv
from bimgame.envs.puzzles import puzzle, vector_env
from bimgame.learn.a3c import A3CConfig
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import NetworkSettings, load_run_network
from bimgame.learn.encoders import CyberRunnerEncoder
from bimgame.learn.nets import NetConfig
from bimgame.learn.ppo import PPOConfig
from support.labyrinth_runs import assert_envs_feed_the_run

CROP = 64 * 64
CLI = ["--obs", "cyberrunner", "--hidden", "16", "--features", "16", "--envs-per-worker", "4", "--n-steps", "32",
       "--eval-every", "0", "--eval-episodes", "2", "--max-episode-steps", "60", "--no-progress"]


@pytest.fixture(autouse=True)
def one_torch_thread():
    """One intra-op thread: the convolutions of a batch of 4 run several times slower on 2 busy cores."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _assert_flat_is(flat: np.ndarray, obs: dict) -> None:
    """``flat`` is ``obs`` laid out as documented, and unflattens to it bit for bit."""
    batch = obs["states"].shape[:-1]
    assert flat.dtype == np.float32 and flat.shape == (*batch, CYBERRUNNER_FLAT_SIZE) == (*batch, CROP + 14)
    np.testing.assert_array_equal(flat[..., :CROP], obs["image"].reshape(*batch, CROP))
    np.testing.assert_array_equal(flat[..., CROP:CROP + 4], obs["states"])
    np.testing.assert_array_equal(flat[..., CROP + 4:], obs["goal"])
    back = unflatten_cyberrunner(flat)
    for key, value in obs.items():
        assert back[key].dtype == value.dtype and np.array_equal(back[key], value), key


def test_the_flat_observation_round_trips_the_dict_in_the_single_and_the_vector_env():
    rng = np.random.default_rng(0)
    single = {mode: LabyrinthEnv("hard", obs_mode=mode, action_type="discrete")
              for mode in ("cyberrunner", "cyberrunner_flat")}
    obs = {mode: env.reset(seed=3)[0] for mode, env in single.items()}
    assert single["cyberrunner_flat"].observation_space.contains(obs["cyberrunner_flat"])
    for _ in range(30):
        _assert_flat_is(obs["cyberrunner_flat"], obs["cyberrunner"])
        action = int(rng.integers(5))
        obs = {mode: env.step(action)[0] for mode, env in single.items()}
    assert obs["cyberrunner"]["image"].std() > 0  # a crop with something in it
    # The vector env, across same-step autoresets: observations and the finished steps' final_obs.
    vector = {mode: LabyrinthVectorEnv(3, "easy", obs_mode=mode, action_type="discrete", max_episode_steps=7)
              for mode in ("cyberrunner", "cyberrunner_flat")}
    obs = {mode: env.reset(seed=1)[0] for mode, env in vector.items()}
    assert vector["cyberrunner_flat"].single_observation_space.shape == (CYBERRUNNER_FLAT_SIZE,)
    finals = 0
    for _ in range(15):
        _assert_flat_is(obs["cyberrunner_flat"], obs["cyberrunner"])
        actions = rng.integers(5, size=3)
        steps = {mode: env.step(actions) for mode, env in vector.items()}
        obs = {mode: step[0] for mode, step in steps.items()}
        flat_info, dict_info = steps["cyberrunner_flat"][4], steps["cyberrunner"][4]
        if "final_obs" in flat_info:
            finals += 1
            _assert_flat_is(flat_info["final_obs"], dict_info["final_obs"])
    assert finals == 2
    # What the learners step: the puzzle's env gives the flat form for obs_mode "cyberrunner".
    env = vector_env("LABYRINTH-EASY", 2, obs_mode="cyberrunner", action_type="discrete")
    flat, _ = env.reset(seed=0)
    _assert_flat_is(flat, LabyrinthVectorEnv(2, "easy", obs_mode="cyberrunner").reset(seed=0)[0])
    _assert_flat_is(flatten_cyberrunner(unflatten_cyberrunner(flat)), unflatten_cyberrunner(flat))


def test_the_encoder_splits_the_flat_observation_and_reads_both_parts():
    flat, _ = vector_env("LABYRINTH-HARD", 4, obs_mode="cyberrunner", action_type="discrete").reset(seed=0)
    parts = unflatten_cyberrunner(flat)
    encoder = CyberRunnerEncoder(CYBERRUNNER_FLAT_SIZE, (16, 32), 24)
    crop, vector = encoder.split(torch.as_tensor(flat))
    assert torch.equal(crop, torch.as_tensor(parts["image"]).float())
    assert torch.equal(vector, torch.as_tensor(np.concatenate([parts["states"], parts["goal"]], axis=-1)))
    obs = torch.as_tensor(flat)
    with torch.no_grad():
        features = encoder(obs)
        assert features.shape == (4, 24) and features.dtype == torch.float32
        changed_crop, changed_vector = obs.clone(), obs.clone()
        changed_crop[:, :CROP] = 255.0 - changed_crop[:, :CROP]  # the crop's negative
        changed_vector[:, CROP:] += 0.5
        for changed in (changed_crop, changed_vector):
            delta = (encoder(changed) - features).abs().amax(dim=1)
            assert bool((delta > 1e-3).all()), delta  # every board's features move
        # bf16 autocast: the same features, roughly, in float32.
        half = CyberRunnerEncoder(CYBERRUNNER_FLAT_SIZE, (16, 32), 24, bf16=True)
        half.load_state_dict(encoder.state_dict())
        bf16 = half(obs)
        assert bf16.dtype == torch.float32 and torch.allclose(bf16, features, atol=0.1)
    # The encoder's weights: conv 16×1×8×8 and 32×16×4×4 (+ biases), vector 14 → 64, FC 1152 + 64 → 24, LayerNorm.
    net = NetworkSettings(obs="cyberrunner", hidden=8, features=24).build_policy(0, puzzle("LABYRINTH-HARD").spec)
    assert isinstance(net.encoder, CyberRunnerEncoder) and net.config.obs_shape == (CYBERRUNNER_FLAT_SIZE,)
    assert sum(p.numel() for p in net.encoder.parameters()) == 16 * 65 + 32 * 257 + 15 * 64 + 1217 * 24 + 48
    logits, values, _ = net.unroll(obs.expand(3, 4, -1), torch.zeros(3, 4, dtype=torch.long), torch.zeros(3, 4),
                                   torch.zeros(3, 4, 2), net.initial_state(4), torch.zeros(3, 4, dtype=torch.bool))
    assert logits.shape == (3, 4, 5) and values.shape == (3, 4)
    with pytest.raises(ValueError, match=r"cyberrunner encoder needs obs_shape \(features,\)"):
        NetConfig(encoder="cyberrunner", obs_shape=(1, 64, 64))
    with pytest.raises(ValueError, match="must hold a crop of 64×64"):
        CyberRunnerEncoder(CROP, (16, 32), 8)


def test_ppo_trains_resumes_and_evaluates_from_cyberrunners_observation(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--task", "LABYRINTH-EASY", "--run-dir", str(run_dir), "--steps", "256",
                 *CLI]) == 0
    assert "done: 256 steps" in capsys.readouterr().out
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["network"]["obs"] == "cyberrunner" and stored["net"]["encoder"] == "cyberrunner"
    assert stored["net"]["obs_shape"] == [CYBERRUNNER_FLAT_SIZE] and stored["network"]["aux_heads"] is False
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--steps", "384",
                 "--no-progress"]) == 0
    assert "done: 384 steps" in capsys.readouterr().out
    net, run, step = load_run_network(run_dir)
    assert (run.task, run.network.obs, step, type(net.encoder)) == ("LABYRINTH-EASY", "cyberrunner", 384,
                                                                   CyberRunnerEncoder)
    result = evaluate_network(net, task=run.task, obs_mode=run.network.obs, episodes=2, seed=0, max_episode_steps=40)
    assert len(result.lengths) == 2 and all(1 <= n <= 40 for n in result.lengths)
    assert main(["evaluate", str(run_dir), "--episodes", "2"]) == 0


def test_what_does_not_apply_is_refused_by_name(tmp_path, capsys):
    maze = r"network\.obs 'cyberrunner' is CyberRunner's observation of the labyrinth .* task STG1 is the circular"
    with pytest.raises(ValueError, match=rf"PPOConfig\.{maze}"):
        PPOConfig.from_flat({"task": "stg1", "obs": "cyberrunner"})
    with pytest.raises(ValueError, match=rf"A3CConfig\.{maze}"):
        A3CConfig.from_flat({"task": "STG1", "obs": "cyberrunner"})
    with pytest.raises(ValueError, match=r"obs_mode 'cyberrunner' is CyberRunner's observation .* task FULL"):
        vector_env("FULL", 2, obs_mode="cyberrunner", action_type="discrete")
    with pytest.raises(ValueError, match="obs 'cyberrunner' is CyberRunner's observation of the labyrinth, not of a"):
        NetworkSettings(obs="cyberrunner").build_policy(0)  # on MERL's maze
    assert main(["train", "--algo", "ppo", "--task", "STG1", "--run-dir", str(tmp_path / "maze"), *CLI]) == 2
    assert "PPOConfig.network.obs 'cyberrunner' is CyberRunner's observation" in capsys.readouterr().err
    assert not (tmp_path / "maze").exists()
    for name, value, why in (("aux_heads", True, "the observation already holds the state the auxiliary heads would predict"),
                             ("keypoints", True, "no keypoints"), ("subtract_background", True, "empty board from a whole-board 84×84 frame"),
                             ("maze_encoding", True, "circular maze's walls"), ("maze_frame", "marble", "turns")):
        with pytest.raises(ValueError, match=rf"NetworkSettings\.{name} does not apply to obs 'cyberrunner': .*{why}"):
            NetworkSettings(obs="cyberrunner", **{name: value})
    # What applies: sizes (the image network's 256 by default), bf16, the tilt input, an asymmetric critic.
    assert (NetworkSettings(obs="cyberrunner").hidden, NetworkSettings(obs="cyberrunner").aux_heads) == (256, False)
    config = PPOConfig.from_flat({"task": "LABYRINTH-MEDIUM", "obs": "cyberrunner", "precision": "bf16",
                                  "asymmetric_critic": True, "tilt_input": False, "hidden": 8, "features": 8})
    net = config.network.build_policy(0, puzzle(config.task).spec)
    assert (net.config.precision, net.config.privileged_size, net.config.tilt_input) == ("bf16", 17, False)


def test_a_run_with_the_marbles_motion_reads_it_in_training_evaluation_and_play(tmp_path, capsys):
    """``--motion``: the network's input is 4112 wide, PPO's envs, the evaluation's and ``bimgame
    play``'s agent all give it the motion (a network of the other width would fail to read them)."""
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--task", "LABYRINTH-EASY", "--run-dir", str(run_dir), "--steps", "128",
                 "--motion", *CLI]) == 0
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["network"]["motion"] is True and stored["net"]["obs_shape"] == [CYBERRUNNER_FLAT_SIZE + 2]
    net = assert_envs_feed_the_run(run_dir, {"motion": True}, (CYBERRUNNER_FLAT_SIZE + 2,))
    assert net.encoder.vector_size == 16  # tilt and position (4), the path ahead (10), the motion (2)
    with pytest.raises(ValueError, match="NetworkSettings.motion applies to obs 'cyberrunner' .* and 'pixels' .* only"):
        NetworkSettings(obs="state", motion=True)
