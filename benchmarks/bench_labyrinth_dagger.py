"""DAgger on CyberRunner's labyrinth: the labyrinth's MPC expert labels the learner's own states,
the aggregated dataset starts from the expert's demonstrations (or, with ``--no-demonstrations``,
empty), and the learner starts from π^s.

Behaviour cloning alone (π^s from 100 expert episodes) falls at 9-11% of the easy layout's path:
its small errors lead it to states the expert never visited. DAgger (Ross et al., 2011) asks the
expert what to do in exactly those states. Each run: ``--iterations`` iterations of
``--episodes-per-iteration`` rollouts (the expert's action executed with probability
β_i = ``beta0 · beta_decay^i``), every visited state labelled, the network retrained on all the data
(``--epochs-per-iteration`` passes). Several seeds with the same settings.

Each run's final network is scored from the layout's own start, greedily and sampling, on
``--episodes`` episodes with the labyrinth's scoring protocol (as ``bench_labyrinth_learning.py``),
and so is its best iterate by the in-run evaluation (``best.pt``: chosen on the run's evaluation
episodes, scored on the protocol's other episodes); across seeds: means with percentile-bootstrap 95%
intervals, per-seed numbers in the JSON. Costs are
reported as DAgger counts them: environment steps of the rollouts, expert labels, and the simulator
steps the expert spent planning them (K·H per label); the demonstrations' steps are counted apart.
With ``--teacher`` a trained policy labels the rollouts instead of the MPC expert
(:mod:`bimgame.learn.dagger.teacher`: e.g. a state policy teaching a pixel learner; ``{seed}`` in the
path is each run's seed). Runs are kept in ``--out``; a rerun resumes unfinished runs and reuses finished ones with their scores.

Writes ``--results`` (default benchmarks/results/labyrinth_dagger.json) and ``--figure`` (default
docs/labyrinth/dagger.png): the in-run evaluation's success and the mean path progress per iteration.

Usage: python benchmarks/bench_labyrinth_dagger.py --expert-data DATA --init PI_S [--layout easy]
       [--obs state|cyberrunner|pixels] [--action-type continuous|discrete] [--surroundings]
       [--motion] [--keypoints] [--subtract-background] [--aux-heads] [--seeds 3] [--iterations 8]
       [--episodes-per-iteration 10] [--beta0 0.5] [--beta-decay 0.7]
       [--epochs-per-iteration 5] [--max-episode-steps 1500] [--demo-start-share 0]
       [--demo-start-window 0 1] [--expert-samples 16]
       [--expert-plans 1] [--expert-sampling hold|uniform|mppi] [--stall-steps N] [--no-demonstrations] [--teacher 'RUNS/seed{seed}/checkpoint.pt']
       [--jobs 3] [--episodes 100]
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from bench_labyrinth_learning import MODES, _aggregate, _score

from bimgame.experiments.run_progress import completed_with_progress, dagger_progress
from bimgame.expert.labyrinth_mpc import LABYRINTH_SAMPLINGS, LabyrinthMPCConfig
from bimgame.learn.dagger import BEST, DAggerConfig, dagger
from bimgame.learn.runs import torch_threads
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.files import atomic_write_bytes, read_json
from bimgame.util.images import save_png, subplots

ROOT = Path(__file__).resolve().parents[1]
#: The labyrinth expert's defaults (K, P), which the flags and the figure's title compare against.
EXPERT = LabyrinthMPCConfig()


def _config(args: argparse.Namespace, seed: int) -> DAggerConfig:
    """One seed's DAgger settings: the learner of π^s (``--obs``, the network's default sizes) on the layout."""
    learner = PretrainConfig(
        task=f"LABYRINTH-{args.layout.upper()}",
        obs=args.obs,
        action_type=args.action_type,
        aux_heads=args.aux_heads,
        asymmetric_critic=False,
        surroundings=args.surroundings,
        motion=args.motion,
        keypoints=args.keypoints,
        subtract_background=args.subtract_background,
        seed=seed,
    )
    return DAggerConfig(
        learner=learner,
        expert_data=None if args.no_demonstrations else str(args.expert_data),
        iterations=args.iterations,
        episodes_per_iteration=args.episodes_per_iteration,
        beta0=args.beta0,
        beta_decay=args.beta_decay,
        demo_start_share=args.demo_start_share,
        demo_start_window=tuple(args.demo_start_window),
        expert=LabyrinthMPCConfig(
            n_samples=args.expert_samples, n_plans=args.expert_plans, sampling=args.expert_sampling
        ),
        teacher=_teacher(args, seed),
        epochs_per_iteration=args.epochs_per_iteration,
        max_episode_steps=args.max_episode_steps,
        stall_steps=args.stall_steps,
        eval_episodes=args.eval_episodes,
    )


def _teacher(args: argparse.Namespace, seed: int) -> str | None:
    """Seed ``seed``'s teacher: ``--teacher`` with ``{seed}`` filled in, as an absolute path."""
    return None if args.teacher is None else str(Path(args.teacher.format(seed=seed)).absolute())


def _window(args: argparse.Namespace) -> str:
    """The title's " at 20–32% of the path" for a demonstration-start window narrower than the whole path."""
    low, high = args.demo_start_window
    return "" if (low, high) == (0.0, 1.0) else f" at {low:.0%}–{high:.0%} of the path"


def _job(run_dir: Path, seed: int, args: argparse.Namespace) -> tuple[float, dict[str, Any], dict[str, Any]]:
    """Run (or resume) and score one seed with one torch thread, its final network and its best
    iterate: a job of ``--jobs``."""
    with torch_threads(1):
        start = time.perf_counter()
        state = read_json(run_dir / "dagger_state.json")
        if state is None or state.get("iteration", 0) < args.iterations:
            dagger(_config(args, seed), run_dir, resume=state is not None, init=args.init, progress=False)
        seconds = time.perf_counter() - start  # 0 for a finished run (its own time: dagger_state.json)
        return seconds, _score(run_dir, args.episodes), _score(run_dir / BEST, args.episodes)


def _arm(args: argparse.Namespace) -> str:
    """The name of the runs' directory under ``--out``: layout, observation and the options that
    change the learner; an option's mark is absent when off (the first runs' names)."""
    marks = (
        (args.action_type != "continuous", f"-{args.action_type}"),
        (args.surroundings, "-surroundings"),
        (args.motion, "-motion"),
        (args.keypoints, "-keypoints"),
        (args.subtract_background, "-nobackground"),
        (args.aux_heads, "-aux"),
        (args.init is not None, "-init"),
        (args.no_demonstrations, "-nodemos"),
        (args.teacher is not None, "-teacher"),
    )
    return f"{args.layout}-{args.obs}" + "".join(mark for on, mark in marks if on)


def _curve(run_dir: Path) -> dict[str, list[float]]:
    """Per iteration: the in-run evaluation's success and mean return, and the run's costs so far."""
    with (run_dir / "dagger.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    keys = ("iteration", "beta", "labels", "expert_sim_steps", "dataset_steps", "rollout_success_rate")
    keys += tuple(f"{mode}_{what}" for mode in MODES for what in ("success_rate", "mean_return", "mean_length"))
    return {key: [float(row[key]) for row in rows] for key in keys}


def _plot(results: dict[str, Any], path: Path, title: str) -> Path:
    fig, (left, right) = subplots(1, 2, figsize=(11, 4), layout="constrained")
    colours = {"greedy": "tab:blue", "sampled": "tab:orange"}
    for k, curve in enumerate(results["curves"]):
        labels = np.array(curve["labels"]) / 1e3
        for mode in MODES:
            label = mode if k == 0 else None
            left.plot(
                labels, 100 * np.array(curve[f"{mode}_success_rate"]), "o-", color=colours[mode], alpha=0.7, label=label
            )
            right.plot(labels, curve[f"{mode}_mean_return"], "o-", color=colours[mode], alpha=0.7, label=label)
    left.set(
        xlabel="expert labels of the learner's states (k)", ylabel="success from the layout's start (%)", ylim=(-3, 103)
    )
    right.set(xlabel="expert labels of the learner's states (k)", ylabel="mean return (path progress × 1.25)")
    for axis in (left, right):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.suptitle(title, fontsize=10, wrap=True)
    return save_png(fig, path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--expert-data", type=Path, default=None, help="the layout's expert dataset (needed unless --no-demonstrations)"
    )
    parser.add_argument(
        "--no-demonstrations",
        action="store_true",
        help="the aggregated dataset starts empty, the expert data's demonstrations left out of it (π^s "
        "still starts the learner): every label is the labelling expert's, in the learner's own states",
    )
    parser.add_argument("--init", type=Path, default=None, help="start every run from this π^s (bimgame pretrain)")
    parser.add_argument("--layout", choices=("easy", "medium", "hard"), default="easy")
    parser.add_argument("--action-type", choices=("continuous", "discrete"), default="continuous")
    parser.add_argument(
        "--obs",
        choices=("state", "cyberrunner", "pixels"),
        default="state",
        help="the learner's observation (π^s's too)",
    )
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed + seeds - 1")
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--episodes-per-iteration", type=int, default=10)
    parser.add_argument("--beta0", type=float, default=0.5)
    parser.add_argument("--beta-decay", type=float, default=0.7)
    parser.add_argument(
        "--demo-start-share",
        type=float,
        default=0.0,
        help="share of each iteration's rollouts started in the expert's states along the path (default 0)",
    )
    parser.add_argument(
        "--demo-start-window",
        type=float,
        nargs=2,
        default=(0.0, 1.0),
        metavar=("FROM", "TO"),
        help="the part of the path (fractions of its length) whose expert states those rollouts start from "
        "(default 0 1: all of it)",
    )
    parser.add_argument(
        "--expert-samples",
        type=int,
        default=EXPERT.n_samples,
        help=f"K, the labelling expert's sampled sequences per decision (default {EXPERT.n_samples})",
    )
    parser.add_argument(
        "--expert-plans",
        type=int,
        default=EXPERT.n_plans,
        help=f"P, independent searches whose first actions the labelling expert averages (default {EXPERT.n_plans})",
    )
    parser.add_argument(
        "--expert-sampling",
        choices=LABYRINTH_SAMPLINGS,
        default=EXPERT.sampling,
        help=f"the labelling expert's sampling (default {EXPERT.sampling}; mppi: a smoothed mean plan)",
    )
    parser.add_argument("--epochs-per-iteration", type=int, default=5)
    parser.add_argument("--max-episode-steps", type=int, default=1500)
    parser.add_argument(
        "--stall-steps",
        type=int,
        default=None,
        help="end a rollout after this many steps without progress along the path (default: never)",
    )
    parser.add_argument("--eval-episodes", type=int, default=20, help="in-run evaluation episodes per iteration")
    parser.add_argument("--episodes", type=int, default=100, help="scoring episodes per mode (default 100)")
    parser.add_argument(
        "--surroundings",
        action="store_true",
        help="state observations with the holes and walls around the marble (π^s must read them too)",
    )
    parser.add_argument(
        "--motion",
        action="store_true",
        help="the marble's motion: CyberRunner's observation with its observed velocity, pixels as two frames (π^s must read it too)",
    )
    parser.add_argument(
        "--keypoints",
        action="store_true",
        help="pixels: spatial soft-argmax keypoints in the conv encoder (π^s must have them too)",
    )
    parser.add_argument(
        "--subtract-background",
        action="store_true",
        help="pixels: subtract the empty board's frame before the convolutions (π^s must too)",
    )
    parser.add_argument(
        "--aux-heads",
        action="store_true",
        help="auxiliary heads that predict the labyrinth's state from the features (the rollouts record it; "
        "π^s may lack them: they are added fresh)",
    )
    parser.add_argument(
        "--teacher",
        default=None,
        help="a trained labyrinth policy that labels the rollouts instead of the MPC expert (its run directory "
        "or a checkpoint in one; '{seed}' in it is each run's seed)",
    )
    parser.add_argument("--jobs", type=int, default=3, help="runs at once, one thread each (default 3)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "labyrinth-dagger")
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "labyrinth_dagger.json")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "labyrinth" / "dagger.png")
    args = parser.parse_args(argv)
    if args.no_demonstrations and args.demo_start_share:
        parser.error(
            "--no-demonstrations and --demo-start-share exclude each other: the demonstration starts are "
            "states of the expert data it leaves out"
        )
    if args.expert_data is None and not args.no_demonstrations:
        parser.error("--expert-data is required: its demonstrations start the aggregated dataset (or give --no-demonstrations)")
    if args.expert_data is not None:
        args.expert_data = args.expert_data.absolute()
    expert_flags = (
        args.expert_samples != EXPERT.n_samples,
        args.expert_plans != EXPERT.n_plans,
        args.expert_sampling != EXPERT.sampling,
    )
    if args.teacher is not None and any(expert_flags):
        parser.error(
            "--teacher labels instead of the MPC expert: drop --expert-samples, --expert-plans and --expert-sampling"
        )
    if args.init is not None:
        args.init = args.init.absolute()
    jobs = {
        seed: args.out / _arm(args) / f"seed{seed}"
        for seed in range(args.first_seed, args.first_seed + args.seeds)
    }
    done: dict[int, tuple[float, dict[str, Any], dict[str, Any]]] = {}
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.jobs, mp_context=context) as pool:
        futures = {pool.submit(_job, run_dir, seed, args): seed for seed, run_dir in jobs.items()}
        for future in completed_with_progress(
            futures, lambda seed: dagger_progress(jobs[seed], args.iterations), name=lambda seed: f"seed {seed}"
        ):
            seed = futures[future]
            done[seed] = future.result()
            for what, scores in (("last", done[seed][1]), ("best", done[seed][2])):
                print(
                    f"seed {seed} ({what}): greedy {scores['greedy_success']:.0%}  sampled "
                    f"{scores['sampled_success']:.0%}  median time sampled {scores['sampled_median_seconds']}  "
                    f"({done[seed][0] / 60:.1f} min)",
                    flush=True,
                )
    seeds = list(jobs)
    per_seed = [done[s][1] for s in seeds]
    best_per_seed = [done[s][2] for s in seeds]
    states = [read_json(jobs[s] / "dagger_state.json") for s in seeds]
    results: dict[str, Any] = {
        "layout": args.layout,
        "obs": args.obs,
        "surroundings": args.surroundings,
        "motion": args.motion,
        "keypoints": args.keypoints,
        "subtract_background": args.subtract_background,
        "aux_heads": args.aux_heads,
        "demonstrations_aggregated": not args.no_demonstrations,
        "teacher": args.teacher,
        "action_type": args.action_type,
        "seeds": seeds,
        "episodes": args.episodes,
        "settings": {k: v for k, v in _config(args, 0).to_dict().items() if k != "learner"},
        "init": None if args.init is None else {"run": str(args.init), "scores": _score(args.init, args.episodes)},
        **_aggregate(per_seed, np.random.default_rng(0)),
        "best_iterate": {
            "iteration_per_seed": [s["best"]["iteration"] for s in states],
            **_aggregate(best_per_seed, np.random.default_rng(1)),
        },
        "costs_per_seed": states,
        "curves": [_curve(jobs[s]) for s in seeds],
    }
    args.results.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(args.results, json.dumps(results, indent=2).encode())
    title = (
        f"DAgger on the {args.layout} labyrinth ({args.obs}{' + surroundings' if args.surroundings else ''}"
        f"{' + motion' if args.motion else ''}{' + keypoints' if args.keypoints else ''}"
        f"{' − empty board' if args.subtract_background else ''}{' + aux heads' if args.aux_heads else ''}, "
        f"{args.action_type}){', from π^s' if args.init else ''}: "
        f"{args.iterations} iterations × {args.episodes_per_iteration} rollouts"
        f"{f' ({args.demo_start_share:.0%} from the expert states{_window(args)})' if args.demo_start_share else ''}"
        f"{', labelled by a trained policy' if args.teacher else ''}"
        f"{f', expert K = {args.expert_samples}' if args.expert_samples != EXPERT.n_samples else ''}"
        f"{f', labels the mean of {args.expert_plans} plans' if args.expert_plans != EXPERT.n_plans else ''}"
        f"{f', {args.expert_sampling} expert' if args.expert_sampling != EXPERT.sampling else ''}"
        f"{f', rollouts end after {args.stall_steps} steps without progress' if args.stall_steps else ''}"
        f"{', no demonstrations in the data' if args.no_demonstrations else ''}, "
        f"seeds {', '.join(map(str, jobs))}"
    )
    print(f"wrote {args.results} and {_plot(results, args.figure, title)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
