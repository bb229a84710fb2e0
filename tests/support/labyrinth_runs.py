"""What a labyrinth run's network reads, checked where every env builder feeds it: shared by the tests
of the observation's extra parts (the marble's motion on CyberRunner's observation and on pixels)."""

from __future__ import annotations

from pathlib import Path

from bimgame.envs.puzzles import puzzle
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import load_run_network
from bimgame.learn.maze_runs import network_env_options
from bimgame.play.agent import AgentPlayer
from bimgame.play.boards import open_board


def assert_envs_feed_the_run(run_dir: Path, env_options: dict, obs_shape: tuple[int, ...]):
    """The evaluation's envs and ``bimgame play``'s agent give the network of ``run_dir`` observations
    it reads (a network of another input shape would fail on them), built with ``env_options``, of
    ``obs_shape``. Returns the loaded network."""
    net, run, _ = load_run_network(run_dir)
    result = evaluate_network(net, task=run.task, obs_mode=run.network.obs, episodes=2, seed=0, max_episode_steps=20,
                              mazes=network_env_options(run.network))
    assert len(result.lengths) == 2
    agent = AgentPlayer(run_dir, puzzle(run.task).spec, task=run.task)
    assert agent.env_options == env_options
    board = open_board(run.task, obs_mode=agent.env_obs_mode, action_type=agent.action_type, **agent.env_options)
    assert board.env.observation_space.shape == obs_shape
    return net


#: A tiny continuous PPO run on the easy layout from state, as settings and as ``bimgame train`` flags:
#: the runs that start from another run's policy (``--init``) and add a part to it.
SMALL_STATE_RUN = dict(task="LABYRINTH-EASY", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=32,
                       eval_every=0, eval_episodes=2, max_episode_steps=100, action_type="continuous")
SMALL_STATE_FLAGS = ["--task", "LABYRINTH-EASY", "--obs", "state", "--hidden", "16", "--features", "16",
                     "--envs-per-worker", "4", "--n-steps", "32", "--eval-every", "0", "--eval-episodes", "2",
                     "--max-episode-steps", "100", "--action-type", "continuous", "--no-progress"]
