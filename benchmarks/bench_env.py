"""Simulator and environment throughput, each as a ratio to the engine's own limit.

The limit is raw ``mj_step`` throughput on the same model (one core) divided by the substeps per
action: no env can step faster than that. This machine's speed drifts by up to ~15% within
minutes, so for the single env the ratio is measured inside the same steps: the share of env-step
wall time spent in ``mj_step`` (timed around each call), which equals env throughput ÷ engine
limit without comparing two runs made at different moments. Measured in the same run:

- engine: physics steps/s of ``mj_step(nstep=5)`` replaying the env benchmark's controls on the
  same trajectory (contacts cost time, so the limit must come from the same states);
- env (state / pixels): ``BallInMazeEnv.step`` with random actions, raw and through ``gym.make``
  (with Gymnasium's TimeLimit/OrderEnforcing/PassiveEnvChecker wrappers);
- vector env: ``BallInMazeVectorEnv`` env steps/s on 1 and 2 threads, state and pixels;
- raster: one 84×84 frame, and per frame in a batch of 64;
- rollout: ``MazeSim.rollout`` physics steps/s on 1 and 2 threads (what the MPC expert uses).

Usage: ``python benchmarks/bench_env.py [--quick]``; writes ``benchmarks/results/env.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

import bimgame  # noqa: F401  (registers ids)
import bimgame.sim.physics as sim_module
from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.sim.physics import MazeSim
from bimgame.sim.render import MazeRenderer
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results" / "env.json"


class _TimedMujoco:
    """Stands in for the ``mujoco`` module inside ``bimgame.sim.physics`` and adds up the time spent in
    ``mj_step``: the engine's share of the very same env steps, immune to the machine's drift."""

    def __init__(self):
        self.seconds = 0.0

    def __getattr__(self, name):
        return getattr(mujoco, name)

    def mj_step(self, *args, **kwargs):
        start = time.perf_counter()
        mujoco.mj_step(*args, **kwargs)
        self.seconds += time.perf_counter() - start


def env_engine_share(obs_mode: str, n: int, wrapped: bool) -> float:
    """Fraction of env-step wall time spent inside ``mj_step`` (best of 3): the env's throughput
    as a fraction of the engine's own limit, measured on the same steps at the same moment."""
    timed = _TimedMujoco()
    original = sim_module.mujoco
    sim_module.mujoco = timed
    try:
        env = gym.make("BiMGame/FULL-v0", obs_mode=obs_mode, max_episode_steps=10 ** 9) if wrapped \
            else BallInMazeEnv("FULL", obs_mode=obs_mode)
        best = 0.0
        for _ in range(3):
            env.reset(seed=0)
            timed.seconds = 0.0
            start = time.perf_counter()
            for action in random_actions(n):
                _, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            best = max(best, timed.seconds / (time.perf_counter() - start))
        return best
    finally:
        sim_module.mujoco = original


def best_of(fn, repeats: int = 3) -> float:
    """Best rate (units/s) over repeats; fn returns (units, seconds)."""
    return max(units / seconds for units, seconds in (fn() for _ in range(repeats)))


def random_actions(n: int) -> list[int]:
    return np.random.default_rng(0).integers(5, size=n).tolist()


def engine_rate(n: int) -> float:
    """Physics steps/s of the bare engine on exactly the trajectory the env benchmarks follow:
    the same start, the same controls (recorded from an env run), ``mj_step(nstep=5)`` per
    action with nothing else in the loop."""
    env = BallInMazeEnv("FULL", obs_mode="state")
    env.reset(seed=0)
    start = env.sim.get_state()
    controls = []
    for action in random_actions(n):
        env.step(action)
        controls.append(env.sim.data.ctrl.copy())
    model, data = env.sim.model, env.sim.data

    def run():
        env.sim.set_state(start)
        begin = time.perf_counter()
        for ctrl in controls:
            data.ctrl[:] = ctrl
            data.qacc_warmstart[:] = 0.0
            mujoco.mj_step(model, data, nstep=5)
        return 5 * len(controls), time.perf_counter() - begin
    return best_of(run, 3)


def env_rate(obs_mode: str, n: int, wrapped: bool) -> float:
    """Env steps/s over the engine benchmark's trajectory (FULL rarely ends by chance; an
    episode that does is reset, which the engine loop does not pay for)."""
    env = gym.make("BiMGame/FULL-v0", obs_mode=obs_mode, max_episode_steps=10 ** 9) if wrapped \
        else BallInMazeEnv("FULL", obs_mode=obs_mode)
    actions = random_actions(n)

    def run():
        env.reset(seed=0)
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return n, time.perf_counter() - start
    return best_of(run, 3)


def vector_rate(obs_mode: str, num_envs: int, steps: int, nthread: int | None = None, *, task: str = "FULL",
                max_episode_steps: int = 1000, **env_kwargs) -> float:
    """Env steps/s of the vector env on ``task`` with random actions (``env_kwargs``: e.g. ``randomize``)."""
    env = BallInMazeVectorEnv(num_envs, task=task, obs_mode=obs_mode, max_episode_steps=max_episode_steps,
                              nthread=nthread, **env_kwargs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(5, size=(steps, num_envs))

    def run():
        start = time.perf_counter()
        for action in actions:
            env.step(action)
        return steps * num_envs, time.perf_counter() - start
    rate = best_of(run, 3)
    env.close()
    return rate


def raster_rate(batch: int, n: int) -> float:
    renderer = MazeRenderer(bimgame.MazeSpec.merl(), 84)
    xy = np.random.default_rng(0).uniform(-0.08, 0.08, size=(batch, 1, 2))
    frame = xy[0] if batch == 1 else xy

    def run():
        start = time.perf_counter()
        for _ in range(n):
            renderer.gray(frame)
        return n * batch, time.perf_counter() - start
    return best_of(run, 5)


def rollout_rate(nthread: int, batch: int = 10, horizon: int = 20, repeats: int = 20) -> float:
    sim = MazeSim()
    sim.reset([[0.0892, 0.0]])
    state = sim.get_state()
    deltas = np.random.default_rng(0).choice([-1, 0, 1], size=(batch, horizon, 2)) * math.radians(1)

    def run():
        start = time.perf_counter()
        for _ in range(repeats):
            sim.rollout(state, deltas, nthread=nthread)
        return repeats * batch * horizon * sim.substeps, time.perf_counter() - start
    rate = best_of(run, 3)
    sim.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps (noisier numbers)")
    args = parser.parse_args()
    scale = 0.2 if args.quick else 1.0
    n = int(20000 * scale)
    # The machine's speed drifts by up to ~15% within minutes: measure the engine before and after
    # the env runs and keep the best, so the limit (and each ratio) is conservative.
    engine_before = engine_rate(n)

    measured = {
        "env, state obs, raw (steps/s)": (env_rate("state", n, False), env_engine_share("state", n, False)),
        "env, state obs, gym.make (steps/s)": (env_rate("state", n, True), env_engine_share("state", n, True)),
        "env, pixel obs, raw (steps/s)": (env_rate("pixels", n, False), env_engine_share("pixels", n, False)),
        "env, pixel obs, gym.make (steps/s)": (env_rate("pixels", n, True), env_engine_share("pixels", n, True)),
        "vector env 16 envs, 1 thread, state (env steps/s)": (vector_rate("state", 16, int(1000 * scale), 1), "limit"),
        "vector env 16 envs, 2 threads, state (env steps/s)": (vector_rate("state", 16, int(1000 * scale), 2), "limit"),
        "vector env 64 envs, 1 thread, state (env steps/s)": (vector_rate("state", 64, int(400 * scale), 1), "limit"),
        "vector env 64 envs, 2 threads, state (env steps/s)": (vector_rate("state", 64, int(400 * scale), 2), "limit"),
        "vector env 64 envs, 2 threads, pixels (env steps/s)": (vector_rate("pixels", 64, int(400 * scale), 2), "limit"),
        "raster 84x84, single frame (frames/s)": (raster_rate(1, int(50000 * scale)), None),
        "raster 84x84, batch of 64 (frames/s)": (raster_rate(64, int(2000 * scale)), None),
        "rollout K=10 H=20, 1 thread (physics steps/s)": (rollout_rate(1), "engine"),
        "rollout K=10 H=20, 2 threads (physics steps/s)": (rollout_rate(2), "engine"),
    }
    engine = max(engine_before, engine_rate(n))
    limit = engine / 5
    rows = {
        "engine mj_step (physics steps/s)": (engine, None),
        "env limit = engine / 5 substeps (env steps/s)": (limit, 1.0),
        **measured,
    }
    table = {}
    print(f"{'measurement':58s} {'rate':>12s} {'ratio':>8s}")
    for name, (rate, ref) in rows.items():
        if isinstance(ref, float) and name.startswith("env,"):
            ratio = ref  # the engine's share of the same steps (see env_engine_share)
        else:
            ratio = rate / limit if ref == "limit" else rate / engine if ref == "engine" else ref
        table[name] = {"rate": rate, "ratio": ratio}
        print(f"{name:58s} {rate:12,.0f} {'' if ratio is None else f'{ratio:8.2f}'}")
    result = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
              "mujoco": mujoco.__version__, "quick": args.quick,
              "time": time.strftime("%Y-%m-%dT%H:%M:%S"), "results": table}
    atomic_write_bytes(RESULTS, json.dumps(result, indent=2).encode())
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
