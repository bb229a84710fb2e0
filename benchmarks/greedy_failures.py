"""Where a maze network's greedy policy fails: each unsuccessful episode from the protocol's starts,
with where the marble ended, how fast it moved at the end and which actions the policy chose then.

A greedy policy that fails where its sampled twin succeeds is often caught in a fixed point: the
marble lies still, the observation repeats, the LSTM settles and the argmax repeats itself. This
replays the run's network greedily from the benchmark protocol's start seeds
(:data:`~bimgame.experiments.protocol.PROTOCOL_SEED`) on MERL's maze, one episode at a time, and
lists each failure's last ``--window`` steps: the actions' counts, the marble's mean speed, its
final position (m) and channel.

Usage: python benchmarks/greedy_failures.py RUN --task STG3 [--episodes 100] [--max-steps 1000]
       [--window 200] [--out FILE]
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bimgame.envs.env import BallInMazeEnv
from bimgame.experiments.protocol import PROTOCOL_SEED
from bimgame.learn.actor import RecurrentActor, tilt_input
from bimgame.learn.common import load_run_network
from bimgame.util.files import write_json
from bimgame.util.seeding import episode_seed


def failure(env: BallInMazeEnv, actor: RecurrentActor, seed: int, max_steps: int, window: int) -> dict | None:
    """One greedy episode from ``seed``; None if it reached the goal, else its last ``window`` steps."""
    obs, info = env.reset(seed=seed)
    actor.reset()
    actions, kinematics = [], []
    for _ in range(max_steps):
        chosen, _, _ = actor.act(obs[None], tilt_input({"tilt": np.asarray(info["tilt"])[None]}, env.maze.max_tilt))
        executed = actor.executed(chosen).numpy()[0]
        obs, reward, terminated, _, info = env.step(executed)
        actor.observe(chosen, np.array([reward]), np.array([terminated]))
        actions.append(int(executed))
        kinematics.append(obs[:4].astype(float))
        if terminated:
            if info["is_success"]:
                return None
            break
    last = np.array(kinematics[-window:])
    return {
        "steps": len(actions),
        "terminated": bool(terminated),
        "final_xy": [round(float(v), 4) for v in last[-1, :2]],
        "final_channel": float(obs[6]),
        "mean_speed_last": float(np.hypot(last[:, 2], last[:, 3]).mean()),
        "actions_last": dict(collections.Counter(actions[-window:]).most_common()),
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a run directory or checkpoint of a maze state network")
    parser.add_argument("--task", default="STG3")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--max-steps", type=int, default=1000)
    parser.add_argument("--window", type=int, default=200)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    net, run, _ = load_run_network(args.run)
    if run.network.obs != "state" or run.network.maze_encoding:
        parser.error(f"{args.run}: a network of MERL's maze from state observations is needed")
    env = BallInMazeEnv(args.task, obs_mode="state", action_type=net.config.action_type)
    actor = RecurrentActor(net.eval(), 1, generator=torch.Generator().manual_seed(0), greedy=True)
    failures = []
    for index in range(args.episodes):
        found = failure(env, actor, episode_seed(PROTOCOL_SEED, index), args.max_steps, args.window)
        if found is not None:
            found = {"seed_index": index, **found}
            failures.append(found)
            print(index, found, flush=True)
    env.close()
    still = sum(f["mean_speed_last"] < 1e-3 for f in failures)
    one_action = sum(len(f["actions_last"]) == 1 for f in failures)
    print(f"{len(failures)} of {args.episodes} failed; marble still {still}, one action repeated {one_action}")
    result = {"run": str(args.run), "task": args.task, "episodes": args.episodes, "max_steps": args.max_steps,
              "window": args.window, "failures": failures, "still": still, "one_action": one_action}  # fmt: skip
    if args.out is not None:
        write_json(args.out, result)
    return result


if __name__ == "__main__":
    main()
