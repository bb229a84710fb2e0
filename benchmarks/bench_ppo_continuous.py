"""PPO with continuous actions (the env's 2-D tilt change, a diagonal Gaussian policy) on STG1 from
state: steps to 80% training success and the final greedy and sampled evaluation (50 episodes) for
several seeds, counted as ``bench_learners.py`` counts them (7.5k-step bins of at least 10 episodes).

Runs are kept in ``--out`` (a rerun reuses the finished ones). Writes
benchmarks/results/ppo_continuous.json.

Usage: python benchmarks/bench_ppo_continuous.py [--steps 200000] [--seeds 3] [--out runs/ppo-continuous]
       [--set NAME=VALUE ...]   (other PPO settings; the measured runs used envs_per_worker=32 n_steps=64)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bench_learners import _measure, _settings

from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.util.files import atomic_write_bytes, read_json

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--bin", type=int, default=7_500)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "ppo-continuous")
    parser.add_argument("--set", nargs="+", default=["envs_per_worker=32", "n_steps=64"], metavar="NAME=VALUE")
    args = parser.parse_args()
    settings = _settings(args.set, parser)
    rows = []
    for seed in range(args.seeds):
        run_dir = args.out / f"seed{seed}"
        summary = read_json(run_dir / "summary.json")
        if summary is None or summary.get("stopped") != "finished":
            config = PPOConfig.from_flat(
                settings,
                task="STG1",
                obs="state",
                action_type="continuous",
                steps=args.steps,
                seed=seed,
                eval_every=0,
                eval_episodes=50,
            )
            train_ppo(config, run_dir, progress=False)
        row, _ = _measure(run_dir, args.steps, args.bin, 0.8)
        rows.append({"seed": seed, **row})
        print(f"seed {seed}: {row}", file=sys.stderr)
    stored = read_json(args.out / "seed0" / "config.json") or {}
    results = {
        "task": "STG1",
        "obs": "state",
        "action_type": "continuous",
        "steps": args.steps,
        "threshold": 0.8,
        "bin": args.bin,
        "settings": stored.get("ppo"),
        "seeds": rows,
    }
    path = ROOT / "benchmarks" / "results" / "ppo_continuous.json"
    atomic_write_bytes(path, (json.dumps(results, indent=1) + "\n").encode())
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
