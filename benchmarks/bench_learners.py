"""bimgame's learners side by side on the same machine, in one run: A3C (2 worker processes × 16
environments) and PPO (16 environments in one process), the same task, observations and step budget
for each, several seeds — with Stable-Baselines3's PPO and sb3-contrib's RecurrentPPO as external
baselines on bimgame's Gymnasium env (16 environments, 1 torch thread; see benchmarks/sb3_baselines.py
for their logs and hyperparameters: SB3's defaults except 128 steps per env per rollout).

For each run: environment steps per second at steady state (the median of the second half of its
updates.csv), steps to 80% training success (training episodes by the step they started at, in bins
of ``--bin`` steps with at least 10 episodes, as the reproduction's report counts them; censored at
the last complete bin when not reached), and the final greedy and sampled evaluation. Across seeds:
each variant's speed-up over A3C in steps to 80% with a stratified bootstrap interval, and a figure of
the learning curves and one of steps/s. Runs are kept in ``--out`` (a rerun reuses the finished ones);
every variant found there is reported (``a3c``, ``ppo-mb4``, ``ppo-mb2`` after ``--ppo-minibatches 2``,
``sb3-ppo``, ``sb3-recurrentppo``, ``sb3-ppo-n2048`` after ``--sb3-n-steps 2048``, …).

**Steps/s only.** ``--sb3-sps-only-steps N`` trains the SB3 variants for N steps instead of the
budget, without evaluation, for learners too slow to train to the budget here (RecurrentPPO from
pixels: tens of steps per second). Such rows say ``"steps/s only, not trained to the budget"`` in
the JSON and the figures, have no steps to 80% and take no part in the speed-ups.

**The SB3 rows** need the optional dependencies: ``pip install -e '.[bench]'`` (stable-baselines3
and sb3-contrib; neither replaces the pinned CPU torch). Without them the script runs the other
learners and says which rows it skipped (``skipped`` in the JSON); naming an unavailable learner in
``--learners`` is an error.

Writes ``--results`` (default benchmarks/results/learners.json for STG1 from state, else
benchmarks/results/learners_<task>_<obs>.json) and, in ``--figure-dir`` (default docs/ppo),
learners_<task>_<obs>.png (learning curves of the variants trained to the budget) and
learners_sps_<task>_<obs>.png (steps/s of every variant).

Usage: python benchmarks/bench_learners.py [--task STG1] [--obs state] [--steps 300000] [--seeds 3]
       [--learners a3c ppo sb3-ppo sb3-recurrentppo] [--out runs/bench-learners]
       [--sb3-sps-only-steps N] [--results PATH] [--figure-dir DIR]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.experiments.statistics import MIN_EPISODES, Crossing, run_crossing, speedup
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.curves import plot_comparison, read_table, run_until
from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.util.files import atomic_write_bytes, read_json
from bimgame.util.images import save_png, subplots

ROOT = Path(__file__).resolve().parents[1]
#: The SB3 variants and the packages (import names, pip names) each needs.
SB3_PACKAGES = {
    "sb3-ppo": {"stable_baselines3": "stable-baselines3"},
    "sb3-recurrentppo": {"stable_baselines3": "stable-baselines3", "sb3_contrib": "sb3-contrib"},
}
LEARNERS = ("a3c", "ppo", *SB3_PACKAGES)
#: SB3's steps per env per rollout in this benchmark (benchmarks/sb3_baselines.py says why).
SB3_N_STEPS = 128
SPS_ONLY = "steps/s only, not trained to the budget"
INSTALL_HINT = "pip install -e '.[bench]'"


def missing_packages(learner: str) -> list[str]:
    """The pip names of the packages ``learner`` needs that are not installed (none for bimgame's own)."""
    needed = SB3_PACKAGES.get(learner, {})
    return [pip for module, pip in needed.items() if importlib.util.find_spec(module) is None]


def _learners(asked: list[str] | None) -> tuple[list[str], dict[str, str]]:
    """The learners to run and those skipped (with why): all available by default; one named in
    ``asked`` whose packages are missing is an error (SystemExit naming them)."""
    if asked is not None:
        for learner in asked:
            if missing := missing_packages(learner):
                raise SystemExit(
                    f"error: --learners {learner} needs {', '.join(missing)}, which is not installed: {INSTALL_HINT}"
                )
        return list(dict.fromkeys(asked)), {}
    skipped = {
        learner: f"not installed: {', '.join(missing)} ({INSTALL_HINT})"
        for learner in LEARNERS
        if (missing := missing_packages(learner))
    }
    return [learner for learner in LEARNERS if learner not in skipped], skipped


def _train(learner: str, run_dir: Path, *, task: str, obs: str, steps: int, seed: int, ppo: dict, sb3: dict) -> None:
    """Train one run unless ``run_dir`` holds a finished one."""
    common = dict(task=task, obs=obs, steps=steps, seed=seed, eval_every=0, eval_episodes=50, envs_per_worker=16)
    if learner in SB3_PACKAGES:
        from sb3_baselines import SB3Run, train_sb3  # needs the optional packages: imported only here

        time_limit = PPOConfig.from_flat(common).time_limit  # the bimgame runs' time limit
        sps_only = sb3["sps_only_steps"] is not None
        budget = sb3["sps_only_steps"] if sps_only else steps
        run = SB3Run(learner, task, obs, budget, seed, time_limit, n_steps=sb3["n_steps"], sps_only=sps_only)
        train_sb3(run, run_dir)
        return
    summary = read_json(run_dir / "summary.json")
    if summary is not None and summary.get("stopped") == "finished":
        return
    if learner == "a3c":
        train(A3CConfig.from_flat(common, workers=2), run_dir, progress=False)
    else:
        train_ppo(PPOConfig.from_flat(common, **ppo), run_dir, progress=False)


def steady_sps(run_dir: Path) -> float:
    """A run's environment steps per second at steady state: the median of the second half of its
    updates.csv (NaN when it logged none)."""
    sps = read_table(run_dir / "updates.csv").get("sps", np.array([]))
    return float(np.median(sps[len(sps) // 2 :])) if len(sps) else float("nan")


def _measure(run_dir: Path, steps: int, bin_steps: int, threshold: float) -> tuple[dict, Crossing | None]:
    """One run's numbers, and its steps to threshold (None for a run only timed)."""
    summary = read_json(run_dir / "summary.json") or {}
    steady = steady_sps(run_dir)
    sps = round(steady) if np.isfinite(steady) else None
    if summary.get("sps_only"):
        row = {"steps_per_second": sps, "trained_steps": summary.get("steps"), "note": SPS_ONLY}
        return row, None
    episodes = read_table(run_dir / "episodes.csv")
    edges = np.arange(0, steps + bin_steps, bin_steps, dtype=np.float64)
    crossing = run_crossing(episodes, edges, threshold, min_episodes=MIN_EPISODES, until=run_until(run_dir, episodes))
    final = summary.get("final_eval") or {}
    row = {
        "steps_to_threshold": crossing.steps,
        "reached": crossing.reached,
        "steps_per_second": sps,
        "final_greedy_success": final.get("greedy_success_rate"),
        "final_sampled_success": final.get("sampled_success_rate"),
    }
    return row, crossing


def _settings(
    pairs: list[str], parser: argparse.ArgumentParser, context: dict[str, object] | None = None
) -> dict[str, object]:
    """``NAME=VALUE`` pairs as PPO flat settings (values read as JSON where they parse: numbers, null),
    checked together with ``context``, the settings the caller's runs have anyway (task, obs …)."""
    settings: dict[str, object] = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        if not sep or name not in PPOConfig.flat_names():
            parser.error(f"--ppo-set takes NAME=VALUE with a PPO setting's flat name, got {pair!r}")
        try:
            settings[name] = json.loads(text)
        except json.JSONDecodeError:
            settings[name] = text
    PPOConfig.from_flat({**(context or {}), **settings})  # refuse bad values now, not after hours of other runs
    return settings


def _variant_names(ppo: dict, sb3_n_steps: int) -> dict[str, str]:
    """Each learner's variant name, which says the settings it was run with where they are not the default."""
    minibatches = PPOConfig.from_flat(ppo).optimization.minibatches
    others = "".join(f"-{key.replace('_', '-')}{value}" for key, value in sorted(ppo.items()) if key != "minibatches")
    suffix = "" if sb3_n_steps == SB3_N_STEPS else f"-n{sb3_n_steps}"
    return {"a3c": "a3c", "ppo": f"ppo-mb{minibatches}{others}", **{name: name + suffix for name in SB3_PACKAGES}}


def _plot_sps(results: dict[str, Any], out: Path, title: str) -> Path:
    """Steps/s of every variant (a bar: the median over its seeds; dots: the seeds), the variants
    only timed hatched and labelled as such."""
    names = list(results["learners"])
    fig, ax = subplots(1, 1, figsize=(8, 0.5 * len(names) + 1.5))
    for index, name in enumerate(names):
        entry = results["learners"][name]
        values = [row["steps_per_second"] for row in entry["seeds"] if row.get("steps_per_second") is not None]
        if not values:
            continue
        only = entry.get("note") == SPS_ONLY
        trained = sorted({row.get("trained_steps") or 0 for row in entry["seeds"]})
        label = f"{name}: {SPS_ONLY} ({', '.join(f'{n:,}' for n in trained)} steps)" if only else None
        ax.barh(
            index,
            float(np.median(values)),
            color="C1" if only else "C0",
            alpha=0.5 if only else 0.8,
            hatch="//" if only else None,
            label=label,
        )
        ax.plot(values, [index] * len(values), "k.")
    ax.set_yticks(range(len(names)), names)
    ax.set(xlabel="environment steps per second", title=title)
    ax.grid(alpha=0.3, axis="x")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    fig.tight_layout()
    return save_png(fig, out, dpi=110)


def _report(args: argparse.Namespace, skipped: dict[str, str]) -> dict[str, Any]:
    """Measure every variant found in ``--out`` (each against A3C); write the JSON and the figures."""
    grid = args.out / f"{args.task}-{args.obs}"
    if not grid.is_dir():
        raise SystemExit(f"error: no runs in {grid}: nothing to report")
    found = {d.name: sorted(d.glob("seed*")) for d in sorted(grid.iterdir()) if d.is_dir()}
    results: dict = {
        "task": args.task,
        "obs": args.obs,
        "steps": args.steps,
        "threshold": args.threshold,
        "bin": args.bin,
        "learners": {},
        "speedup_over_a3c": {},
        "skipped": skipped,
    }
    crossings: dict[str, list[Crossing]] = {}
    for name, dirs in found.items():
        measured = [_measure(d, args.steps, args.bin, args.threshold) for d in dirs]
        results["learners"][name] = {"seeds": [row for row, _ in measured]}
        if any(c is None for _, c in measured):
            results["learners"][name]["note"] = SPS_ONLY
        else:
            crossings[name] = [c for _, c in measured if c is not None]
    for name in crossings:
        if name != "a3c" and "a3c" in crossings:
            rng = np.random.default_rng(0)
            results["speedup_over_a3c"][name] = speedup(crossings["a3c"], crossings[name], rng=rng)
    default = "learners.json" if (args.task, args.obs) == ("STG1", "state") else f"learners_{args.task}_{args.obs}.json"
    out_json = args.results or ROOT / "benchmarks" / "results" / default
    atomic_write_bytes(out_json, (json.dumps(results, indent=1) + "\n").encode())
    written = [out_json]
    title = f"{args.task} from {args.obs}"
    # Learning curves of the variants trained to the budget (no cut at --steps: every run has that
    # budget, and its final evaluation lies one update past it).
    trained = {name: found[name] for name in crossings}
    if trained:
        written.append(plot_comparison(trained, args.figure_dir / f"learners_{args.task}_{args.obs}.png", title=title))
    else:
        print("no variant trained to the budget: no learning-curve figure", file=sys.stderr)
    written.append(_plot_sps(results, args.figure_dir / f"learners_sps_{args.task}_{args.obs}.png", title))
    print(json.dumps(results, indent=1))
    print(f"wrote {', '.join(map(str, written))}", file=sys.stderr)
    return results


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
    parser.add_argument(
        "--ppo-set",
        nargs="+",
        default=[],
        metavar="NAME=VALUE",
        help="other PPO settings by flat name (e.g. sequence_length=16 envs_per_worker=32); they name the variant",
    )
    parser.add_argument(
        "--learners",
        nargs="+",
        choices=LEARNERS,
        default=None,
        help=f"the learners to run (default: all available of {', '.join(LEARNERS)})",
    )
    parser.add_argument(
        "--sb3-n-steps",
        type=int,
        default=SB3_N_STEPS,
        help=f"SB3's steps per env per rollout (default {SB3_N_STEPS}; other values name the variant sb3-…-nN)",
    )
    parser.add_argument(
        "--sb3-sps-only-steps",
        type=int,
        default=None,
        metavar="N",
        help="train the SB3 variants only N steps, to measure their steps/s (reported as not trained to the budget)",
    )
    parser.add_argument("--results", type=Path, default=None, help="the JSON to write (default: see above)")
    parser.add_argument("--figure-dir", type=Path, default=ROOT / "docs" / "ppo", help="where the figures go")
    args = parser.parse_args(argv)
    for name in ("steps", "seeds", "bin", "sb3_n_steps", "sb3_sps_only_steps"):
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {value}")
    learners, skipped = _learners(args.learners)
    for learner, why in skipped.items():
        print(f"skipped {learner}: {why}", file=sys.stderr)
    ppo = {} if args.ppo_minibatches is None else {"minibatches": args.ppo_minibatches}
    ppo.update(_settings(args.ppo_set, parser))
    sb3 = {"n_steps": args.sb3_n_steps, "sps_only_steps": args.sb3_sps_only_steps}
    names = _variant_names(ppo, args.sb3_n_steps)
    for seed in range(args.seeds):
        for learner in learners:
            run_dir = args.out / f"{args.task}-{args.obs}" / names[learner] / f"seed{seed}"
            print(f"{learner} seed {seed} -> {run_dir}", file=sys.stderr)
            _train(learner, run_dir, task=args.task, obs=args.obs, steps=args.steps, seed=seed, ppo=ppo, sb3=sb3)
    _report(args, skipped)
    return 0


if __name__ == "__main__":
    sys.exit(main())
