"""The learners on CyberRunner's labyrinth (bimgame.envs.puzzles): the tasks and what they map to, the
settings that accept them and those that refuse them by name, a tiny PPO run from the command line
(run directory, resume, evaluate) and a tiny A3C run, and success counted from the env's own ``success`` — a marble in a
hole terminates its episode but is no success; and both learners from the labyrinth's pixels (its own
84×84 frames and empty board; two frames with the marble's motion), with only what is made for the maze's
state layout refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import bimgame.envs.labyrinth_env as labyrinth_env
from bimgame.cli.main import main
from bimgame.envs.puzzles import LABYRINTH, MAZE, TASK_NAMES, puzzle, state_obs_scale, vector_env
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.actor import RecurrentActor, episode_successes, evaluate_network, tilt_input
from bimgame.learn.common import NetworkSettings, load_run_network
from bimgame.learn.learner_settings import check_init_puzzle, policy_network
from bimgame.learn.pixel_network import empty_board_frame
from bimgame.learn.ppo import PPOConfig
from bimgame.learn.rollout import RolloutCollector, training_env
from bimgame.play.agent import AgentPlayer
from bimgame.play.boards import open_board
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_render import board_grid
from bimgame.sim.maze import MazeSpec
from bimgame.sim.tasks import Task
from support.labyrinth_runs import assert_envs_feed_the_run

LAB = dict(task="LABYRINTH-EASY", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=32,
           eval_every=0, eval_episodes=2, max_episode_steps=100)
CLI = ["--obs", "state", "--hidden", "16", "--features", "16", "--envs-per-worker", "4", "--n-steps", "32",
       "--eval-every", "0", "--eval-episodes", "2", "--max-episode-steps", "100", "--no-progress"]
#: On the easy board with a hole 32.5 mm west of the start, on the path, discrete action 4 (tilt −1
#: step about y) rolls the marble into it within 20 steps.
INTO_THE_HOLE = 4


def test_every_task_maps_to_its_puzzle_case_insensitively():
    assert TASK_NAMES == ("FULL", "STG1", "STG2", "STG3", "STG4", "LABYRINTH-EASY", "LABYRINTH-MEDIUM",
                          "LABYRINTH-HARD")
    for task in Task:
        found = puzzle(task.value.lower())
        assert (found.task, found.family, found.time_limit) == (task.value, MAZE, task.time_limit)
        assert found.spec == MazeSpec.merl()
    hard = puzzle("Labyrinth-Hard")
    assert (hard.task, hard.family, hard.layout, hard.time_limit) == ("LABYRINTH-HARD", LABYRINTH, "hard", 3000)
    with pytest.raises(ValueError, match=r"unknown task 'LABYRINTH_EASY'; allowed: FULL, STG1, .*LABYRINTH-HARD$"):
        puzzle("LABYRINTH_EASY")
    # The maze's divisors: rim radius, 0.5 m/s, maximum tilt, outermost channel; the labyrinth's bring
    # its 17 values to order 1.
    merl = MazeSpec.merl()
    np.testing.assert_allclose(
        state_obs_scale(merl),
        [merl.rim_radius, merl.rim_radius, 0.5, 0.5, merl.max_tilt, merl.max_tilt, merl.outermost_channel],
        rtol=1e-6,
    )
    scale = puzzle("LABYRINTH-EASY").state_obs_scale()
    assert scale.shape == (17,) and np.all(scale > 0)
    np.testing.assert_allclose(scale[:7], [0.138, 0.1155, 0.5, 0.5, np.radians(10), np.radians(10), 1.0], rtol=1e-6)
    env = vector_env("labyrinth-easy", 2, obs_mode="state", action_type="discrete", randomize=None, start_sampler=None)
    obs, _ = env.reset(seed=0)
    assert np.all(np.abs(obs / scale) <= 2.0) and env.max_episode_steps == 3000
    with pytest.raises(ValueError, match=r"num_mazes, randomize: the circular maze's options, not the labyrinth's"):
        vector_env("LABYRINTH-EASY", 2, obs_mode="state", action_type="discrete", randomize=object(), num_mazes=3)
    assert isinstance(training_env(2, task="STG1", obs="state", time_limit=10, privileged=False), BallInMazeVectorEnv)


def test_settings_accept_the_labyrinth_and_refuse_the_mazes_settings_by_name():
    config = PPOConfig.from_flat(LAB, task="labyrinth-medium", action_type="continuous", asymmetric_critic=True)
    assert config.task == "LABYRINTH-MEDIUM" and config.time_limit == 100
    assert PPOConfig.from_flat(LAB, max_episode_steps=None).time_limit == 3000
    net = policy_network(config)
    assert net.config.obs_shape == (17,) and net.config.privileged_size == 17
    assert torch.equal(net.encoder.scale, torch.as_tensor(puzzle("LABYRINTH-MEDIUM").state_obs_scale()))
    assert A3CConfig.from_flat(LAB).task == "LABYRINTH-EASY"
    refused = {
        "num_mazes": r"PPOConfig\.num_mazes applies to the circular maze's tasks only, not LABYRINTH-EASY: random",
        "start_maze": r"PPOConfig\.start_maze applies to the circular maze's tasks only",
    }
    values = {"num_mazes": 4, "start_maze": 2}
    for name, message in refused.items():
        with pytest.raises(ValueError, match=message):
            PPOConfig.from_flat(LAB, **{name: values[name]})
    # Pixels run on the labyrinth's own frames, their auxiliary heads off there by default (see the
    # pixel tests below).
    assert PPOConfig.from_flat(LAB, obs="pixels").network.aux_heads is False
    assert PPOConfig.from_flat(LAB, obs="cyberrunner").network.obs == "cyberrunner"  # test_cyberrunner_encoder.py
    for name, value, why in (("randomize", "physics", "domain randomisation"),
                             ("expert_data", "data", "only demonstration starts .* read the expert's datasets")):
        with pytest.raises(ValueError, match=rf"A3CConfig\.{name} applies to the circular maze's tasks only.*{why}"):
            A3CConfig.from_flat(LAB, **{name: value})
    with pytest.raises(ValueError, match=r"A3CConfig\.bc_coef applies to the circular maze's tasks only.*pre-train"):
        A3CConfig.from_flat(LAB, start_curriculum="demo", expert_data="data", bc_coef=0.1)
    # Both start curricula run on the labyrinth: demonstration starts from its expert's data, the reverse
    # curriculum along its path.
    for config in (A3CConfig, PPOConfig):
        with pytest.raises(ValueError, match=rf"{config.__name__}\.start_curriculum='demo' needs expert_data"):
            config.from_flat(LAB, start_curriculum="demo")
        assert config.from_flat(LAB, start_curriculum="demo", expert_data="data").expert_data == "data"
        assert config.from_flat(LAB, start_curriculum="reverse").curriculum.start_curriculum == "reverse"
    with pytest.raises(ValueError, match=r"PPOConfig\.task: unknown task 'labyrinth'; allowed: FULL, .*LABYRINTH-EASY"):
        PPOConfig.from_flat(LAB, task="labyrinth")


def test_ppo_trains_resumes_and_evaluates_on_the_labyrinth_from_the_command_line(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--task", "labyrinth-easy", "--run-dir", str(run_dir), "--steps", "256",
                 *CLI]) == 0
    assert "done: 256 steps" in capsys.readouterr().out
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["task"] == stored["ppo"]["task"] == "LABYRINTH-EASY" and stored["net"]["obs_shape"] == [17]
    assert {"checkpoint.pt", "episodes.csv", "updates.csv", "eval.csv", "summary.json"} <= {
        p.name for p in run_dir.iterdir()}
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--steps", "384",
                 "--no-progress"]) == 0
    assert "done: 384 steps" in capsys.readouterr().out
    net, run, step = load_run_network(run_dir)
    assert (run.task, run.time_limit, step, net.config.obs_shape) == ("LABYRINTH-EASY", 100, 384, (17,))
    assert main(["evaluate", str(run_dir), "--episodes", "2"]) == 0
    capsys.readouterr()
    # What the maze's verbs cannot do with it, and the maze's reward shaping, are refused by name.
    assert main(["evaluate", str(run_dir), "--task", "STG1"]) == 2
    assert "was trained on LABYRINTH-EASY (the labyrinth)" in capsys.readouterr().err
    assert main(["score", str(run_dir)]) == 2
    assert "bimgame score runs the circular maze's benchmark protocol" in capsys.readouterr().err
    assert main(["train", "--task", "LABYRINTH-EASY", "--run-dir", str(tmp_path / "g"), "--geodesic-reward", *CLI]) == 2
    assert "RewardSettings.geodesic_coef applies to the circular maze's tasks only" in capsys.readouterr().err
    # A network of one puzzle starts no run on the other: its observations differ.
    with pytest.raises(ValueError, match=r"--init: the network of .* was trained on LABYRINTH-EASY \(the labyrinth\)"):
        check_init_puzzle(run_dir, "STG1")
    assert main(["train", "--algo", "ppo", "--task", "STG1", "--init", str(run_dir), "--run-dir",
                 str(tmp_path / "m"), *CLI]) == 2
    assert "start it from scratch" in capsys.readouterr().err and not (tmp_path / "m").exists()
    check_init_puzzle(run_dir, "LABYRINTH-HARD")  # the same puzzle: its network fits
    # DAgger takes the labyrinth's tasks too (its expert), but not a network of the other puzzle.
    assert main(["dagger", "--task", "STG1", "--obs", "state", "--init", str(run_dir), "--run-dir",
                 str(tmp_path / "p"), "--no-progress"]) == 2
    assert "start it from scratch" in capsys.readouterr().err and not (tmp_path / "p").exists()


def test_a3c_trains_on_the_labyrinth_too(tmp_path):
    config = A3CConfig.from_flat(LAB, steps=256, workers=1, n_steps=16, max_episode_steps=50)
    result = train(config, tmp_path / "a3c", progress=False)
    assert result.steps >= 256 and result.final_eval is not None
    net, run, _ = load_run_network(tmp_path / "a3c")
    assert (run.task, net.config.obs_shape, net.config.action_type) == ("LABYRINTH-EASY", (17,), "discrete")


class _HoleyBoard(LabyrinthSpec):
    """The easy board with one more hole on the path, 32.5 mm west of the start."""

    @classmethod
    def layout(cls, name, **overrides):
        board = LabyrinthSpec.layout(name, **overrides)
        return board.replace(holes=board.holes + ((-0.03, 0.1065),))


def _into_the_hole(config: PPOConfig):
    """The run's network, acting (greedily, and almost always when sampling) with :data:`INTO_THE_HOLE`."""
    net = policy_network(config)
    with torch.no_grad():
        net.policy.weight.zero_()
        net.policy.bias.copy_(torch.tensor([0.0, 0.0, 0.0, 0.0, 12.0]))
    return net


def test_an_episode_that_ends_in_a_hole_is_no_success(monkeypatch):
    monkeypatch.setattr(labyrinth_env, "LabyrinthSpec", _HoleyBoard)
    config = PPOConfig.from_flat(LAB)
    net = _into_the_hole(config)
    result = evaluate_network(net, task=config.task, obs_mode="state", episodes=3, seed=0, max_episode_steps=100)
    assert result.lengths == [20, 20, 20]  # terminated, long before the time limit
    assert result.successes == [False, False, False]
    # The collector books them as failures too.
    env = training_env(4, task=config.task, obs="state", time_limit=100, privileged=False)
    booked = []
    collector = RolloutCollector(env, env, RecurrentActor(net, 4, generator=torch.Generator().manual_seed(0)),
                                 gamma=0.99, on_episode=booked.append)
    collector.reset(0, 0)
    segment = collector.collect(24, 0)
    assert len(booked) == 4 and segment.ends.any()
    assert all(not episode.success and episode.length < 100 for episode in booked)


def test_success_is_the_envs_own_where_it_reports_one_else_a_termination():
    terminated = np.array([True, True, False])
    # Same-step autoreset: the finished step's info says which episodes succeeded (the info beside it
    # is the next episode's).
    info = {"is_success": np.zeros(3, dtype=bool), "final_info": {"is_success": np.array([True, False, False])}}
    assert episode_successes(info, terminated).tolist() == [True, False, False]
    assert episode_successes({"is_success": np.array([False, True, True])}, terminated).tolist() == [False, True, False]
    # An env that reports nothing: a termination is its goal.
    assert episode_successes({}, terminated).tolist() == [True, True, False]


#: The flags of a tiny run from the labyrinth's pixels (the learner's --n-steps and --steps apart).
PIXELS = ["--task", "LABYRINTH-EASY", "--obs", "pixels", "--hidden", "16", "--features", "16", "--envs-per-worker",
          "4", "--eval-every", "0", "--eval-episodes", "2", "--max-episode-steps", "50", "--no-progress"]


def test_the_pixel_network_reads_the_labyrinths_frames_and_subtracts_its_empty_board():
    config = PPOConfig.from_flat(LAB, obs="pixels", action_type="continuous", subtract_background=True,
                                 asymmetric_critic=True, keypoints=True, precision="bf16")
    net = policy_network(config)
    env = training_env(3, task=config.task, obs="pixels", time_limit=100, privileged=True, action_type="continuous")
    obs, info = env.reset(seed=0)
    assert env.single_observation_space.shape == net.config.obs_shape == (1, 84, 84) and obs.dtype == np.uint8
    assert info["state"].shape == (3, net.config.privileged_size) == (3, 17)
    # The background is the labyrinth's empty board: a frame differs from it only at its marble (≈ 3.5 px wide).
    spec = puzzle(config.task).spec
    background = net.encoder.background.numpy()
    np.testing.assert_array_equal(background, empty_board_frame(spec))
    grid = board_grid(spec, 84)
    for frame, state in zip(obs, info["state"], strict=True):
        rows, cols = np.nonzero(frame[0] != background[0])
        col, row = grid.to_pixel(state[:2])
        assert 4 <= len(rows) <= 25 and np.all(np.hypot(cols - col, rows - row) < 3.0)
    assert not np.array_equal(background, empty_board_frame(puzzle("LABYRINTH-HARD").spec))  # its holes, walls
    # One step acting: the bf16 conv encoder with keypoints, the tilt input, a critic reading the 17 values.
    with torch.no_grad():
        mean, values, _ = net.step(torch.as_tensor(obs), torch.zeros(3, 2), torch.zeros(3),
                                   tilt_input(info, env.maze.max_tilt), net.initial_state(3),
                                   privileged=torch.as_tensor(info["state"]))
    assert mean.shape == (3, 2) and values.shape == (3,) and torch.isfinite(values).all()


def test_ppo_trains_resumes_and_evaluates_on_the_labyrinth_from_pixels(tmp_path, capsys):
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--action-type", "continuous", "--subtract-background",
                 "--asymmetric-critic", "--n-steps", "32", "--run-dir", str(run_dir), "--steps", "256", *PIXELS]) == 0
    assert "done: 256 steps" in capsys.readouterr().out
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["net"]["obs_shape"] == [1, 84, 84] and stored["net"]["privileged_size"] == 17
    assert stored["ppo"]["aux_heads"] is False and stored["net"]["subtract_background"] is True
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--steps", "384",
                 "--no-progress"]) == 0
    assert "done: 384 steps" in capsys.readouterr().out
    net, run, step = load_run_network(run_dir)
    assert (run.network.obs, step, net.config.obs_shape, net.config.action_type) == (
        "pixels", 384, (1, 84, 84), "continuous")
    fresh = policy_network(PPOConfig.from_flat(stored["ppo"]))
    assert not torch.equal(net.encoder.conv1.weight, fresh.encoder.conv1.weight)  # it learned
    assert torch.equal(net.encoder.background, fresh.encoder.background)
    out = tmp_path / "eval.json"
    assert main(["evaluate", str(run_dir), "--episodes", "2", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["task"] == "LABYRINTH-EASY" and len(result["lengths"]) == 2
    assert all(1 <= length <= 50 for length in result["lengths"])


def test_a3c_trains_and_evaluates_on_the_labyrinth_from_pixels(tmp_path, capsys):
    run_dir = tmp_path / "a3c"
    # One worker; frames shifted by up to 2 px (the rim leaves 2.2 px around the marble).
    assert main(["train", "--workers", "1", "--n-steps", "16", "--augment-shift", "2", "--run-dir", str(run_dir),
                 "--steps", "128", *PIXELS]) == 0
    assert "done: 128 steps" in capsys.readouterr().out
    net, run, step = load_run_network(run_dir)
    assert (run.task, run.network.obs, run.network.aux_heads, net.config.obs_shape, net.config.action_type) == (
        "LABYRINTH-EASY", "pixels", False, (1, 84, 84), "discrete")
    assert step >= 128
    out = tmp_path / "eval.json"
    assert main(["evaluate", str(run_dir), "--episodes", "2", "--sample", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert (result["task"], result["mode"], len(result["lengths"])) == ("LABYRINTH-EASY", "sampled", 2)


def test_the_pixel_network_reads_two_frames_with_the_background_under_each():
    """``motion`` on pixels (bimgame.envs.labyrinth_pixels): the conv network reads the previous frame
    and the current one, and subtracts the empty board from each."""
    spec = puzzle("LABYRINTH-EASY").spec
    net = policy_network(PPOConfig.from_flat(LAB, obs="pixels", motion=True, subtract_background=True))
    assert net.config.obs_shape == (2, 84, 84) and net.encoder.conv1.in_channels == 2
    background = net.encoder.background.numpy()
    np.testing.assert_array_equal(background, np.repeat(empty_board_frame(spec), 2, axis=0))
    assert policy_network(PPOConfig.from_flat(LAB, obs="pixels")).config.obs_shape == (1, 84, 84)
    with pytest.raises(ValueError, match=r"PPOConfig\.motion on STG1: it is part of the labyrinth's observations"):
        PPOConfig.from_flat(LAB, task="STG1", obs="pixels", motion=True)
    with pytest.raises(ValueError, match=r"NetworkSettings\.motion applies to obs 'cyberrunner' .* and 'pixels'"):
        NetworkSettings(obs="state", motion=True)


def test_a_pixel_run_with_the_marbles_motion_reads_two_frames_in_training_evaluation_and_play(tmp_path, capsys):
    """``--motion`` on pixels: PPO's envs, the evaluation's and ``bimgame play``'s agent all give the
    network two frames (a one-frame network would fail to read them)."""
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--action-type", "continuous", "--motion", "--n-steps", "32",
                 "--run-dir", str(run_dir), "--steps", "128", *PIXELS]) == 0
    assert "done: 128 steps" in capsys.readouterr().out
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["network"]["motion"] is True and stored["net"]["obs_shape"] == [2, 84, 84]
    assert_envs_feed_the_run(run_dir, {"motion": True}, (2, 84, 84))


def test_the_labyrinth_refuses_by_name_only_what_its_pixels_cannot_train_with():
    for config in (PPOConfig, A3CConfig):
        owner = config.__name__
        with pytest.raises(ValueError, match=rf"{owner}\.maze_encoding on LABYRINTH-EASY: the encoding is of a "
                                             r"circular maze's walls; leave it off \(maze_encoding=False\)"):
            config.from_flat(LAB, maze_encoding=True)
        # The rest of the pixel network runs on the labyrinth.
        network = config.from_flat(LAB, obs="pixels", subtract_background=True, keypoints=True, tilt_input=False,
                                   asymmetric_critic=True, precision="fp32").network
        assert (network.aux_heads, network.subtract_background, network.keypoints) == (False, True, True)
    # The maze's pixels keep their heads by default; the labyrinth's are asked for (below).
    assert PPOConfig.from_flat(LAB, task="STG1", obs="pixels").network.aux_heads is True


def test_a_runs_off_path_rule_reaches_its_training_envs_and_is_refused_where_there_is_no_path(tmp_path, capsys):
    """``off_path_rule`` goes from the settings (and ``bimgame train --off-path-rule``) into every env
    the run builds — training's vector env, the single env of its rollouts, ``bimgame play``'s board;
    absent, the env's default and no key, so the env arguments of earlier runs are unchanged."""
    assert PPOConfig.from_flat(LAB).maze_options == {}
    config = PPOConfig.from_flat(LAB, off_path_rule="cyberrunner", action_type="continuous")
    assert config.maze_options == {"off_path_rule": "cyberrunner"}
    envs = training_env(2, task=config.task, obs="state", time_limit=20, privileged=False,
                        action_type="continuous", **config.maze_options)
    single = puzzle(config.task).env(obs_mode="state", action_type="continuous", **config.maze_options)
    assert envs.template.off_path_rule == single.off_path_rule == "cyberrunner"
    assert single.path_sight is not None  # CyberRunner's free-box map, which the default rule does not build
    envs.close()
    single.close()
    for learner in (A3CConfig, PPOConfig):
        with pytest.raises(ValueError, match=rf"{learner.__name__}\.off_path_rule must be one of \('tolerance', "
                                             r"'cyberrunner'\) or None, got 'box'"):
            learner.from_flat(LAB, off_path_rule="box")
        with pytest.raises(ValueError, match=rf"{learner.__name__}\.off_path_rule applies to the labyrinth's tasks "
                                             r"only, not STG1"):
            learner.from_flat(dict(LAB, task="STG1"), off_path_rule="cyberrunner")
    with pytest.raises(ValueError, match="off_path_rule is the labyrinth's .*, not STG1's"):
        puzzle("STG1").env(obs_mode="state", action_type="discrete", off_path_rule="cyberrunner")
    # The flag: stored in the run's config, kept on --resume; refused on the maze by name.
    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--task", "LABYRINTH-EASY", "--run-dir", str(run_dir), "--steps", "128",
                 "--off-path-rule", "cyberrunner", "--action-type", "continuous", *CLI]) == 0
    assert json.loads((run_dir / "config.json").read_text())["ppo"]["off_path_rule"] == "cyberrunner"
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--steps", "256",
                 "--no-progress"]) == 0
    assert json.loads((run_dir / "config.json").read_text())["ppo"]["off_path_rule"] == "cyberrunner"
    capsys.readouterr()
    assert main(["train", "--algo", "ppo", "--run-dir", str(run_dir), "--resume", "--steps", "384",
                 "--off-path-rule", "tolerance", "--no-progress"]) == 2
    assert "changed: off_path_rule ('cyberrunner' -> 'tolerance')" in capsys.readouterr().err
    # bimgame play opens its board under the rule the agent trained under.
    agent = AgentPlayer(run_dir, puzzle("LABYRINTH-EASY").spec, task="LABYRINTH-EASY")
    assert agent.env_options == {"off_path_rule": "cyberrunner"}
    board = open_board("LABYRINTH-EASY", obs_mode=agent.env_obs_mode, action_type=agent.action_type,
                       **agent.env_options)
    assert board.env.off_path_rule == "cyberrunner"
    board.close()
    capsys.readouterr()
    # bimgame score plays the protocol's rule unless asked, and says which rule the run trained under.
    assert main(["score", str(run_dir), "--task", "LABYRINTH-EASY", "--episodes", "1", "--no-progress"]) == 0
    assert "note: the run trained under the off-path rule cyberrunner; scored under tolerance" in " ".join(
        capsys.readouterr().out.split())
    assert main(["score", str(run_dir), "--task", "LABYRINTH-EASY", "--episodes", "1", "--off-path-rule",
                 "cyberrunner", "--no-progress"]) == 0
    assert "note:" not in capsys.readouterr().out
    assert main(["train", "--task", "STG1", "--run-dir", str(tmp_path / "m"), "--off-path-rule", "cyberrunner",
                 *CLI]) == 2
    assert "off_path_rule applies to the labyrinth's tasks only, not STG1" in capsys.readouterr().err
    assert not (tmp_path / "m").exists()


def test_a_runs_fail_reward_is_what_its_envs_pay_for_a_fall_and_is_refused_on_the_maze():
    """``fail_reward`` (``bimgame train --fail-reward``) is the training reward of the step that ends an
    episode in a hole or off the path; absent, the env's own (0) and no key."""
    config = PPOConfig.from_flat(LAB, fail_reward=-1.0, action_type="continuous")
    assert config.maze_options == {"fail_reward": -1.0}
    envs = training_env(2, task=config.task, obs="state", time_limit=20, privileged=False,
                        action_type="continuous", **config.maze_options)
    assert envs.template.fail_reward == -1.0
    envs.close()
    env = puzzle(config.task).env(obs_mode="state", action_type="continuous", **config.maze_options)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(3000):  # random tilting loses the marble long before the time limit
        _, reward, terminated, _, info = env.step(rng.uniform(-1.0, 1.0, 2).astype(np.float32))
        if terminated:
            break
    assert terminated and not info["is_success"] and reward == -1.0
    env.close()
    with pytest.raises(ValueError, match=r"PPOConfig\.fail_reward must be a finite number or None, got inf"):
        PPOConfig.from_flat(LAB, fail_reward=float("inf"))
    with pytest.raises(ValueError, match=r"A3CConfig\.fail_reward applies to the labyrinth's tasks only, not STG1"):
        A3CConfig.from_flat(dict(LAB, task="STG1"), fail_reward=-1.0)
