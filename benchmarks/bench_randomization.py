"""What domain randomisation (``randomize=``, :mod:`bimgame.envs.randomization`) costs.

- reset: per-episode physics set on the built MuJoCo model (``MazeSim.set_parameters``) against
  rebuilding the model from a changed ``MazeSpec``, and a whole ``BallInMazeEnv.reset`` with and
  without physics randomisation;
- vector env: ``BallInMazeVectorEnv`` env steps/s on 64 envs (default threads), pixels and state,
  with ``randomize=None``, with camera-only randomisation (pixels) and with physics and actuation
  randomisation (one model per env in the one ``mujoco.rollout`` call);
- camera transforms alone on a batch of 64 frames.

Each setting runs a few seconds (best of 3 repeats); rates are relative to ``randomize=None`` in the
same run, since the machine's speed drifts.

Usage: ``python benchmarks/bench_randomization.py [--steps N]``; writes
``benchmarks/results/randomization.json``.
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
from bimgame.envs.randomization import EpisodeRandomizer, Randomization
from bimgame.sim.maze import Friction, MazeSpec
from bimgame.sim.physics import MazeSim
from bimgame.sim.render import MazeRenderer
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results" / "randomization.json"

PHYSICS_RANGES = dict(sliding_friction=(0.7, 1.3), torsional_friction=(0.7, 1.3), rolling_friction=(0.7, 1.3),
                      marble_mass=(0.8, 1.2), marble_radius=(0.95, 1.03), max_tilt=(0.8, 1.2), tilt_step=(0.8, 1.2),
                      tilt_error=(0.0, 0.2), latency=(0, 2))
CAMERA_RANGES = dict(brightness=(-20.0, 20.0), contrast=(0.8, 1.2), pixel_noise=(0.0, 5.0), blur=(0.0, 1.0),
                     camera_shift=(-2.0, 2.0), camera_rotation=(-5.0, 5.0))
PHYSICS = Randomization(**PHYSICS_RANGES)
CAMERA = Randomization(**CAMERA_RANGES)
BOTH = Randomization(**PHYSICS_RANGES, **CAMERA_RANGES)


def set_parameters_us(n: int) -> tuple[float, float]:
    """µs per ``set_parameters`` on the built model, and per model rebuilt from a changed spec."""
    spec = MazeSpec.merl()
    sim = MazeSim(spec)
    rng = np.random.default_rng(0)
    scales = rng.uniform(0.9, 1.03, size=(n, 4))

    def field_setting():
        start = time.perf_counter()
        for a, b, c, d in scales:
            sim.set_parameters(friction=Friction(slide=0.5 * a), marble_mass=spec.marble_mass * b,
                               marble_radius=spec.marble_radius * c, max_tilt=spec.max_tilt * d)
        return n, time.perf_counter() - start

    def rebuild():
        start = time.perf_counter()
        for a, b, c, d in scales[: max(1, n // 20)]:
            MazeSim(spec.replace(friction=Friction(slide=0.5 * a), marble_mass=spec.marble_mass * b,
                                 marble_radius=spec.marble_radius * c, max_tilt=spec.max_tilt * d))
        return max(1, n // 20), time.perf_counter() - start
    return 1e6 / best_of(field_setting), 1e6 / best_of(rebuild)


def env_reset_us(randomize: Randomization | None, n: int) -> float:
    env = BallInMazeEnv("FULL", obs_mode="state", randomize=randomize)

    def run():
        start = time.perf_counter()
        for seed in range(n):
            env.reset(seed=seed)
        return n, time.perf_counter() - start
    return 1e6 / best_of(run)


def camera_ms(n: int, batch: int = 64) -> float:
    """ms per batch of ``batch`` frames for the camera transforms alone (all of CAMERA's effects)."""
    spec = MazeSpec.merl()
    raster = MazeRenderer(spec, 84)
    randomizer = EpisodeRandomizer(CAMERA, spec, batch, raster)
    rng = np.random.default_rng(0)
    for row in range(batch):
        randomizer.reset_row(row, rng)
    xy = rng.uniform(-0.06, 0.06, size=(batch, 1, 2))
    frames = raster.gray(xy)[:, None]
    steps = np.zeros(batch, dtype=np.int64)

    def run():
        start = time.perf_counter()
        for _ in range(n):
            randomizer.pixels(frames.copy(), steps, xy)
        return n, time.perf_counter() - start
    return 1e3 / best_of(run)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150,
                        help="vector env steps (of 64 envs) per repeat and setting (default 150: ~1-3 s)")
    args = parser.parse_args()
    steps = max(10, args.steps)
    field_us, rebuild_us = set_parameters_us(200)
    rows: dict[str, tuple[float, str, float | None]] = {
        "physics parameters: set on the model (µs per reset)": (field_us, "µs", None),
        "physics parameters: rebuild the model (µs per reset)": (rebuild_us, "µs", None),
        "env.reset, randomize=None (µs)": (env_reset_us(None, 200), "µs", None),
        "env.reset, physics + actuation randomised (µs)": (env_reset_us(PHYSICS, 200), "µs", None),
        "camera transforms, batch of 64 frames (ms)": (camera_ms(100), "ms", None),
    }
    for obs_mode, settings in (("pixels", (("randomize=None", None), ("camera only", CAMERA),
                                           ("physics + actuation", PHYSICS), ("physics + actuation + camera", BOTH))),
                               ("state", (("randomize=None", None), ("physics + actuation", PHYSICS)))):
        baseline = None
        for label, randomize in settings:
            rate = vector_rate(obs_mode, 64, steps, randomize=randomize)
            baseline = baseline or rate
            rows[f"vector env 64 envs, {obs_mode}, {label} (env steps/s)"] = (rate, "steps/s", rate / baseline)
    table = {}
    print(f"{'measurement':66s} {'value':>12s} {'vs None':>8s}")
    for name, (value, unit, ratio) in rows.items():
        table[name] = {"value": value, "unit": unit, "ratio_to_none": ratio}
        print(f"{name:66s} {value:12,.1f} {'' if ratio is None else f'{ratio:8.2f}'}")
    result = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
              "mujoco": mujoco.__version__, "steps": steps, "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
              "results": table}
    atomic_write_bytes(RESULTS, json.dumps(result, indent=2).encode())
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
