"""bimgame's learners side by side on the same machine, in one run: A3C (2 worker processes × 16
environments) and PPO (16 environments in one process), the same task, observations and step budget
for each, several seeds.

For each run: environment steps per second at steady state (the median of the second half of its
updates.csv), steps to 80% training success (training episodes by the step they started at, in bins
of ``--bin`` steps with at least 10 episodes, as the reproduction's report counts them; censored at
the last complete bin when not reached), and the final greedy and sampled evaluation. Across seeds:
each variant's speed-up over A3C in steps to 80% with a stratified bootstrap interval, and a figure of
the learning curves. Runs are kept in ``--out`` (a rerun reuses the finished ones); every variant found
there is reported (``a3c``, ``ppo-mb4``, ``ppo-mb2`` after ``--ppo-minibatches 2``, …). Writes
benchmarks/results/learners.json and docs/ppo/learners_<task>_<obs>.png.

Usage: python benchmarks/bench_learners.py [--task STG1] [--obs state] [--steps 300000] [--seeds 3]
       [--out runs/bench-learners]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bimgame.experiments.statistics import MIN_EPISODES, Crossing, run_crossing, speedup
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.curves import plot_comparison, read_table, run_until
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.util.files import atomic_write_bytes, read_json

ROOT = Path(__file__).resolve().parents[1]
LEARNERS = ("a3c", "ppo")


def _train(learner: str, run_dir: Path, *, task: str, obs: str, steps: int, seed: int, ppo: dict) -> None:
    """Train one run unless ``run_dir`` holds a finished one."""
    summary = read_json(run_dir / "summary.json")
    if summary is not None and summary.get("stopped") == "finished":
        return
    common = dict(task=task, obs=obs, steps=steps, seed=seed, eval_every=0, eval_episodes=50, envs_per_worker=16)
    if learner == "a3c":
        train(A3CConfig.from_flat(common, workers=2), run_dir, progress=False)
    else:
        train_ppo(PPOConfig.from_flat(common, **ppo), run_dir, progress=False)


def _measure(run_dir: Path, steps: int, bin_steps: int, threshold: float) -> tuple[dict, Crossing]:
    """One run's numbers, and its steps to threshold."""
    episodes = read_table(run_dir / "episodes.csv")
    edges = np.arange(0, steps + bin_steps, bin_steps, dtype=np.float64)
    crossing = run_crossing(episodes, edges, threshold, min_episodes=MIN_EPISODES, until=run_until(run_dir, episodes))
    sps = read_table(run_dir / "updates.csv")["sps"]
    steady = float(np.median(sps[len(sps) // 2 :]))
    final = (read_json(run_dir / "summary.json") or {}).get("final_eval") or {}
    row = {
        "steps_to_threshold": crossing.steps,
        "reached": crossing.reached,
        "steps_per_second": round(steady),
        "final_greedy_success": final.get("greedy_success_rate"),
        "final_sampled_success": final.get("sampled_success_rate"),
    }
    return row, crossing


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="STG1")
    parser.add_argument("--obs", default="state", choices=("state", "pixels"))
    parser.add_argument("--steps", type=int, default=300_000)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--bin", type=int, default=7_500, help="steps per bin of training success (default 7500)")
    parser.add_argument("--threshold", type=float, default=0.8)
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "bench-learners")
    parser.add_argument("--ppo-minibatches", type=int, default=None, help="PPO's minibatches (default: PPO's own)")
    parser.add_argument("--learners", nargs="+", choices=LEARNERS, default=list(LEARNERS))
    args = parser.parse_args(argv)
    ppo = {} if args.ppo_minibatches is None else {"minibatches": args.ppo_minibatches}
    minibatches = PPOConfig.from_flat(ppo).optimization.minibatches
    names = {"a3c": "a3c", "ppo": f"ppo-mb{minibatches}"}
    for seed in range(args.seeds):
        for learner in args.learners:
            run_dir = args.out / f"{args.task}-{args.obs}" / names[learner] / f"seed{seed}"
            print(f"{learner} seed {seed} -> {run_dir}", file=sys.stderr)
            _train(learner, run_dir, task=args.task, obs=args.obs, steps=args.steps, seed=seed, ppo=ppo)
    # Every variant whose runs are in --out is reported (a3c, ppo-mb4, ppo-mb2, …), each against A3C.
    grid = args.out / f"{args.task}-{args.obs}"
    found = {d.name: sorted(d.glob("seed*")) for d in sorted(grid.iterdir()) if d.is_dir()}
    results: dict = {"task": args.task, "obs": args.obs, "steps": args.steps, "threshold": args.threshold,
                     "bin": args.bin, "learners": {}, "speedup_over_a3c": {}}
    crossings: dict[str, list[Crossing]] = {}
    for name, dirs in found.items():
        measured = [_measure(d, args.steps, args.bin, args.threshold) for d in dirs]
        crossings[name] = [c for _, c in measured]
        results["learners"][name] = {"seeds": [row for row, _ in measured]}
    for name in crossings:
        if name != "a3c" and "a3c" in crossings:
            rng = np.random.default_rng(0)
            results["speedup_over_a3c"][name] = speedup(crossings["a3c"], crossings[name], rng=rng)
    out_json = ROOT / "benchmarks" / "results" / "learners.json"
    atomic_write_bytes(out_json, (json.dumps(results, indent=1) + "\n").encode())
    figure = ROOT / "docs" / "ppo" / f"learners_{args.task}_{args.obs}.png"
    figure.parent.mkdir(parents=True, exist_ok=True)
    # No cut at --steps: every run has that budget, and its final evaluation lies one update past it.
    plot_comparison(found, figure, title=f"{args.task} from {args.obs}")
    print(json.dumps(results, indent=1))
    print(f"wrote {out_json} and {figure}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
