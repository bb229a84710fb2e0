"""What drawing a maze per episode (``num_mazes``, :mod:`bimgame.sim.maze_sets`) costs the vector env.

Env steps/s of ``BallInMazeVectorEnv`` on STG2 with random actions, at STG2 episode lengths: episodes
cut at ``--episode-steps`` (default 150, about the MPC expert's STG2 episodes; 500 is STG2's time
limit), so that every env starts a new episode — and draws a new maze — every that many steps. Each
of one maze (MERL's, ``num_mazes=None``), 100 mazes (their specs, models' wall pieces and pictures
cached after the first use) and unlimited mazes (a new maze per episode: generated, its pieces
computed and, for pixels, its raster drawn), for state and pixel observations and 16 and 64 envs;
for state observations also unlimited mazes with gate bearings (``gate_bearings=True``).
Rates are relative to one maze in the same round (the machine's speed drifts; unlimited mazes with
gate bearings relative to one maze with them, ``num_mazes=1``): every setting is
measured once per round, ``--rounds`` rounds, and the table gives the medians of the rates and of
the per-round ratios (each round's in the JSON). Also: the µs of one
``BallInMazeEnv.reset`` in each setting, and of ``MazeSim.set_walls`` against building a model.
Every measurement starts with the per-process maze caches empty (:func:`clear_maze_caches`): the
settings draw the same maze numbers from the same seeds, and an unlimited setting would otherwise find
an earlier setting's mazes ready.

The issue's goal: mazes change with at most 10% loss of the vector env's steps/s.

Usage: ``python benchmarks/bench_mazes.py [--episode-steps N] [--steps N] [--rounds N] [--results PATH]``; writes
``--results`` (default ``benchmarks/results/mazes.json``).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import mujoco
import numpy as np
from bench_env import best_of, vector_rate  # benchmarks/ is the script's directory, on sys.path

from bimgame.envs.env import BallInMazeEnv
from bimgame.envs.mazes import maze_encoding, maze_raster
from bimgame.sim.maze import MazeSpec
from bimgame.sim.maze_sets import maze_number
from bimgame.sim.mjcf import wall_slots
from bimgame.sim.physics import MazeSim, _slot_geometry
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results" / "mazes.json"
#: The settings compared: label and ``num_mazes``.
SETTINGS = (("one maze", None), ("100 mazes", 100), ("unlimited", 0))
#: State observations only: unlimited mazes with gate bearings (``gate_bearings=True``), against one
#: maze with them (a set of one maze, ``num_mazes=1``): the bearings are an observation's cost, the
#: same with one maze or many, and the goal is about what changing mazes costs.
BEARINGS = "unlimited, gate bearings"
BEARINGS_ONE = "one maze, gate bearings"


def clear_maze_caches() -> None:
    """Forget the mazes built so far in this process: specs, wall pieces, encodings and pictures."""
    for cache in (maze_number, _slot_geometry, maze_encoding, maze_raster):
        cache.cache_clear()


def maze_vector_rate(
    obs_mode: str, num_envs: int, steps: int, episode_steps: int, num_mazes: int | None, gate_bearings: bool = False
) -> float:
    """Env steps/s of the vector env on STG2 with random actions, episodes cut at ``episode_steps``."""
    clear_maze_caches()
    kwargs: dict = {} if num_mazes is None else {"num_mazes": num_mazes}
    if gate_bearings:
        kwargs["gate_bearings"] = True
    return vector_rate(obs_mode, num_envs, steps, 1, task="STG2", max_episode_steps=episode_steps, **kwargs)


def reset_us(obs_mode: str, num_mazes: int | None, n: int = 200) -> float:
    """µs per ``BallInMazeEnv.reset`` (a new maze each time with ``num_mazes``)."""
    clear_maze_caches()
    kwargs = {} if num_mazes is None else {"num_mazes": num_mazes}
    env = BallInMazeEnv("STG2", obs_mode=obs_mode, **kwargs)
    env.reset(seed=0)

    def run():
        start = time.perf_counter()
        for _ in range(n):
            env.reset()
        return n, time.perf_counter() - start

    return 1e6 / best_of(run)


def switch_us(n: int = 100) -> tuple[float, float]:
    """µs per ``MazeSim.set_walls`` to a new maze (pieces not cached), and per model built for it."""
    base = MazeSpec.merl()
    slots = wall_slots(base, 4)
    sim = MazeSim(base, wall_slots=slots)
    offset = [10_000]

    def switch():
        mazes = [maze_number(offset[0] + i) for i in range(n)]
        offset[0] += n
        start = time.perf_counter()
        for maze in mazes:
            sim.set_walls(maze)
        return n, time.perf_counter() - start

    def build():
        mazes = [maze_number(i) for i in range(n // 10)]
        start = time.perf_counter()
        for maze in mazes:
            MazeSim(maze, wall_slots=slots)
        return len(mazes), time.perf_counter() - start

    return 1e6 / best_of(switch), 1e6 / best_of(build)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episode-steps", type=int, default=150, help="steps per episode (default 150)")
    parser.add_argument("--steps", type=int, default=600, help="vector env steps per repeat (default 600)")
    parser.add_argument(
        "--rounds", type=int, default=5, help="measurements of every setting, interleaved; medians (default 5)"
    )
    parser.add_argument("--results", type=Path, default=RESULTS, help="default benchmarks/results/mazes.json")
    args = parser.parse_args()
    switch, build = switch_us()
    rows: dict[str, tuple[float, str, float | None]] = {
        "MazeSim.set_walls to a new maze (µs)": (switch, "µs", None),
        "MazeSim built for a maze (µs)": (build, "µs", None),
    }
    for obs_mode in ("state", "pixels"):
        for label, num_mazes in SETTINGS:
            rows[f"env.reset, {obs_mode}, {label} (µs)"] = (reset_us(obs_mode, num_mazes), "µs", None)
    ratios: dict[str, list[float]] = {}
    rates: dict[str, list[float]] = {}
    for _ in range(args.rounds):  # every setting once per round: drift hits them alike
        for obs_mode in ("state", "pixels"):
            for num_envs in (16, 64):
                baselines: dict[bool, float] = {}  # one maze's rate, without and with gate bearings
                settings = [(label, n, False) for label, n in SETTINGS]
                settings += [(BEARINGS_ONE, 1, True), (BEARINGS, 0, True)] if obs_mode == "state" else []
                for label, num_mazes, bearings in settings:
                    rate = maze_vector_rate(obs_mode, num_envs, args.steps, args.episode_steps, num_mazes, bearings)
                    baseline = baselines.setdefault(bearings, rate)
                    name = f"vector env {num_envs} envs, {obs_mode}, {label} (env steps/s)"
                    rates.setdefault(name, []).append(rate)
                    ratios.setdefault(name, []).append(rate / baseline)
    for name, values in rates.items():
        rows[name] = (float(np.median(values)), "steps/s", float(np.median(ratios[name])))
    table = {}
    print(f"{'measurement':62s} {'value':>12s} {'vs one maze':>12s}")
    for name, (value, unit, ratio) in rows.items():
        table[name] = {"value": value, "unit": unit, "ratio_to_one_maze": ratio}
        print(f"{name:62s} {value:12,.1f} {'' if ratio is None else f'{ratio:12.2f}'}")
    result = {
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "episode_steps": args.episode_steps,
        "steps": args.steps,
        "rounds": args.rounds,
        "ratios_per_round": ratios,
        "rates_per_round": rates,
        "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "results": table,
    }
    atomic_write_bytes(args.results, json.dumps(result, indent=2).encode())
    print(f"wrote {args.results}")


if __name__ == "__main__":
    main()
