"""Env steps/s of the labyrinth next to the circular maze's, in one run on one machine.

Measured, single process, one thread (``OMP_NUM_THREADS=1``), the raw env (no Gymnasium wrappers):

- ``LabyrinthEnv`` on each layout (easy, medium, hard), ``obs_mode`` state and pixels (84×84),
  55 Hz (its default: 3 physics substeps per action), continuous random actions;
- ``BallInMazeEnv`` on STG1 (30 Hz, 5 substeps), state and pixels, discrete random actions;
- the batched vector envs the learners step, ``--vector-envs`` (32) boards each, one thread, same-step
  autoreset, state observations: ``LabyrinthVectorEnv`` on the hard layout (continuous random
  actions) beside ``BallInMazeVectorEnv`` on STG1 (discrete), in env steps/s (boards × vector steps);
- the labyrinth's physics alone (``LabyrinthSim.step``) and its path-progress rule alone
  (``PathProgress.update``, batched numpy, and ``ScalarPathProgress.update``, the env's scalar
  fast path) on the hard layout: where the env's time goes.

Episodes that end are reset (the reset counts in the time). Each configuration runs ``--repeats``
times, interleaved with the others so that a drift of the machine's speed hits all alike; the
median is reported. The machine may be shared with other jobs: ``os.getloadavg()`` is recorded
before and after. The issue's goal is a labyrinth within 0.8 of the circular maze's steps/s.

Usage: ``python benchmarks/bench_labyrinth.py [--steps N] [--vector-steps M] [--vector-envs B] [--repeats R]``;
writes ``benchmarks/results/labyrinth_env.json``. The vector rows compare with the circular maze's
vector row (``ratio_to_circular_maze``) and with the same single env (``ratio_to_single_env``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.envs.labyrinth_vector import LabyrinthVectorEnv
from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.sim.labyrinth import LabyrinthSpec, PathProgress
from bimgame.sim.labyrinth_physics import LabyrinthSim
from bimgame.sim.labyrinth_tracker import ScalarPathProgress
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results" / "labyrinth_env.json"


def env_rate(make: Callable[[], object], steps: int, seed: int = 0) -> Callable[[], float]:
    """A timer of ``steps`` random steps of a fresh env from ``make``, in env steps/s: a vector env's
    step counts each of its boards (finished episodes reset inside its step), a single env's
    finished episode is reset between steps."""
    env = make()
    boards = getattr(env, "num_envs", None)

    def run() -> float:
        env.action_space.seed(seed)  # type: ignore[attr-defined]
        env.reset(seed=seed)  # type: ignore[attr-defined]
        actions = [env.action_space.sample() for _ in range(steps)]  # type: ignore[attr-defined]
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)  # type: ignore[attr-defined]
            if boards is None and (terminated or truncated):
                env.reset()  # type: ignore[attr-defined]
        return steps * (boards or 1) / (time.perf_counter() - start)

    return run


def sim_rate(steps: int) -> Callable[[], float]:
    """Steps/s of the hard layout's physics alone, small random tilt changes."""
    sim = LabyrinthSim(LabyrinthSpec.layout("hard"), control_hz=55)
    deltas = np.random.default_rng(0).uniform(-1, 1, (steps, 2)) * np.radians(30) / 55

    def run() -> float:
        sim.reset(sim.spec.start)
        start = time.perf_counter()
        for delta in deltas:
            sim.step(delta)
        return steps / (time.perf_counter() - start)

    return run


def path_rate(steps: int, scalar: bool) -> Callable[[], float]:
    """Updates/s of the path-progress rule alone (numpy's or the env's scalar one), along the hard
    layout's first segment."""
    spec = LabyrinthSpec.layout("hard")
    tracker = ScalarPathProgress(spec) if scalar else PathProgress(spec)
    a, b = np.array(spec.waypoints[0]), np.array(spec.waypoints[1])
    points = [(a + (b - a) * t).tolist() for t in np.linspace(0, 1, steps)]

    def run() -> float:
        tracker.reset(points[0])
        start = time.perf_counter()
        for p in points:
            tracker.update(p)
        return steps / (time.perf_counter() - start)

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=1500, help="steps per timing")
    parser.add_argument("--vector-steps", type=int, default=150, help="vector steps per timing of the vector envs")
    parser.add_argument("--vector-envs", type=int, default=32, help="boards of each vector env")
    parser.add_argument("--repeats", type=int, default=3, help="timings per configuration (median reported)")
    args = parser.parse_args()
    load_before = os.getloadavg()
    timers: dict[str, Callable[[], float]] = {}
    for layout in ("easy", "medium", "hard"):
        for obs_mode in ("state", "pixels"):
            timers[f"labyrinth {layout}, {obs_mode}"] = env_rate(
                lambda layout=layout, obs_mode=obs_mode: LabyrinthEnv(layout, obs_mode=obs_mode), args.steps
            )
    for obs_mode in ("state", "pixels"):
        timers[f"circular maze STG1, {obs_mode}"] = env_rate(
            lambda obs_mode=obs_mode: BallInMazeEnv("STG1", obs_mode=obs_mode), args.steps
        )
    b = args.vector_envs
    vector_name = f"labyrinth hard, vector ×{b}, state"
    timers[vector_name] = env_rate(
        lambda: LabyrinthVectorEnv(b, "hard", nthread=1, autoreset_mode="same_step"), args.vector_steps
    )
    timers[f"circular maze STG1, vector ×{b}, state"] = env_rate(
        lambda: BallInMazeVectorEnv(b, task="STG1", obs_mode="state", nthread=1, autoreset_mode="same_step"),
        args.vector_steps,
    )
    timers["labyrinth hard, physics only (LabyrinthSim.step)"] = sim_rate(args.steps)
    timers["labyrinth hard, path rule only (PathProgress.update, numpy)"] = path_rate(args.steps, False)
    timers["labyrinth hard, path rule only (ScalarPathProgress.update, the env's)"] = path_rate(args.steps, True)
    samples: dict[str, list[float]] = {name: [] for name in timers}
    for _ in range(args.repeats):
        for name, timer in timers.items():
            samples[name].append(timer())
    rates = {name: statistics.median(values) for name, values in samples.items()}
    results = {}
    for name, rate in rates.items():
        mode = "pixels" if name.endswith("pixels") else "state"
        vector = ", vector ×" in name
        compared = name.startswith("labyrinth") and "only" not in name
        reference = rates[f"circular maze STG1, {f'vector ×{b}, ' if vector else ''}{mode}"] if compared else None
        ratio = None if reference is None else rate / reference
        results[name] = {"steps_per_s": rate, "ratio_to_circular_maze": ratio, "samples": samples[name]}
        if vector:  # the batched env against its own single env
            single = rates["labyrinth hard, state" if name.startswith("labyrinth") else "circular maze STG1, state"]
            results[name]["ratio_to_single_env"] = rate / single
        print(f"{name:72s} {rate:9.0f} steps/s" + ("" if ratio is None else f"   ×{ratio:.2f} of the circular maze's"))
    load_after = os.getloadavg()
    print(f"load average before {load_before}, after {load_after} ({os.cpu_count()} CPUs)")
    report = {
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "steps": args.steps,
        "vector_steps": args.vector_steps,
        "vector_envs": args.vector_envs,
        "repeats": args.repeats,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "loadavg_before": load_before,
        "loadavg_after": load_after,
        "note": "raw envs, one thread; labyrinth at 55 Hz (3 substeps), circular maze at 30 Hz (5 substeps); "
        "vector rows in env steps/s (boards x vector steps), same-step autoreset",
        "results": results,
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(RESULTS, (json.dumps(report, indent=2) + "\n").encode())
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
