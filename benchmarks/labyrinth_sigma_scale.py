"""How much of a labyrinth policy's sampled failures is its Gaussian's noise: each run's final
network scored sampling (the labyrinth protocol, ``--episodes`` episodes from the benchmark's score
seed) with its learned standard deviation σ multiplied by each of ``--scales`` (1: the policy as
trained; 0.5: half the noise, the same mean). A diagnostic of trained weights, not a training
result: a scale other than 1 is not the policy PPO learned.

Each scaled policy is a copy of the run's ``config.json`` and checkpoint with log σ + log(scale), in
a temporary directory. Across runs: means with percentile-bootstrap 95% intervals (runs resampled).

Usage: python benchmarks/labyrinth_sigma_scale.py RUN [RUN ...] [--task LABYRINTH-EASY]
       [--scales 1 0.5] [--episodes 100] [--jobs 3] [--results FILE]
"""

from __future__ import annotations

import argparse
import math
import multiprocessing
import shutil
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from bench_labyrinth_learning import SCORE_SEED

from bimgame.experiments.labyrinth_protocol import score_labyrinth
from bimgame.experiments.statistics import mean_interval
from bimgame.learn.checkpoints import load_checkpoint, save_checkpoint
from bimgame.learn.runs import CHECKPOINT, CONFIG, torch_threads
from bimgame.util.files import write_json
from bimgame.util.processes import exit_when_parent_dies

ROOT = Path(__file__).resolve().parents[1]


def _score(run: Path, scale: float, task: str, episodes: int) -> dict[str, Any]:
    """Sampled protocol numbers of ``run``'s final network with σ times ``scale`` (one torch thread)."""
    payload = load_checkpoint(run / CHECKPOINT)
    model = dict(payload["model"])
    if "log_std" not in model:
        raise SystemExit(f"{run} is not a continuous-action (Gaussian) policy: it has no log_std")
    model["log_std"] = model["log_std"] + math.log(scale)
    with tempfile.TemporaryDirectory() as directory, torch_threads(1):
        scaled = Path(directory)
        shutil.copy(run / CONFIG, scaled / CONFIG)
        save_checkpoint(scaled / CHECKPOINT, model=model, step=payload["step"])
        summary = score_labyrinth(str(scaled), task, episodes=episodes, sampled=True, seed=SCORE_SEED, progress=False)
    return {
        "run": str(run),
        "scale": scale,
        "sigma": [float(s) for s in np.exp(model["log_std"].numpy())],
        "success": summary["success_rate"],
        "mean_return": summary["mean_return"],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="PPO or DAgger run directories on the labyrinth")
    parser.add_argument("--task", default="LABYRINTH-EASY")
    parser.add_argument("--scales", nargs="+", type=float, default=[1.0, 0.5])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--jobs", type=int, default=3)
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "labyrinth_sigma_scale.json")
    args = parser.parse_args(argv)
    for scale in args.scales:
        if not (math.isfinite(scale) and scale > 0):
            parser.error(f"--scales must be positive numbers, got {scale!r}")
    for run in args.runs:
        if not (run / CHECKPOINT).is_file() or not (run / CONFIG).is_file():
            parser.error(f"{run} is not a run directory (no {CONFIG} and {CHECKPOINT})")
    jobs = [(run.absolute(), scale) for scale in args.scales for run in args.runs]
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context, initializer=exit_when_parent_dies) as pool:
        rows = list(pool.map(_score, *zip(*jobs, strict=True), [args.task] * len(jobs), [args.episodes] * len(jobs)))
    rng = np.random.default_rng(0)
    summary = {}
    for scale in args.scales:
        values = np.array([row["success"] for row in rows if row["scale"] == scale])
        low, high = mean_interval(values, rng=rng)
        summary[str(scale)] = {"per_run": values.tolist(), "mean": float(values.mean()), "interval": [low, high]}
        print(f"σ × {scale:g}: sampled success {' / '.join(f'{v:.0%}' for v in values)} "
              f"(mean {values.mean():.0%} [{low:.0%}, {high:.0%}])")
    write_json(args.results, {"task": args.task, "episodes": args.episodes, "score_seed": SCORE_SEED,
                              "scales": summary, "runs": rows})
    print(f"wrote {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
