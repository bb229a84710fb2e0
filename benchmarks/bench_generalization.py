"""Generalization to unseen mazes (Procgen/CoinRun's protocol, on random circular mazes).

Each learner is trained on N random training mazes (``--num-mazes``: N = 1, 10, 100, 1000 and 0 =
unlimited, a new maze every episode; :mod:`bimgame.sim.maze_sets`) for the same step budget, several
seeds, and its final network is scored, greedily and sampling, on

- **train**: episode k on training maze k mod min(N, 100) — the mazes it trained on (for N > 100 and
  unlimited, the first 100 training mazes: mazes it may have met);
- **test**: episode k on held-out test maze k, k < ``--episodes`` (100 by default) — mazes no
  training set contains (their hashes are in the test partition).

With ``--learners pretrain+ppo+keep`` and ``--pretrain-data DATA`` (an expert dataset on many training
mazes: ``bimgame generate --num-mazes``), a π^s per seed is first pre-trained on DATA and scored on
the same splits (the "pre-trained only" row), then PPO starts from it with the registry's
``pretrain+ppo+keep`` settings (its KL to π^s) and ``--set``'s (PPO from random weights keeps its
defaults).

``--learners dagger`` runs DAgger on the same mazes (``DAggerConfig.num_mazes``; the maze expert
planning with the geodesic reward labels every visited state): ``--dagger-iterations`` iterations of
``--dagger-episodes`` rollouts each, a budget in episodes rather than ``--steps`` (the environment
steps it used are in the JSON's ``steps_scored``, and it also spends the expert's planning).

``--gate-bearings`` gives every run's state observations each wall's nearest gate as seen from the
marble (``NetworkSettings.gate_bearings``: :mod:`bimgame.envs.gate_bearings`), read beside the encoding.

``--geodesic-reward COEF`` trains every run on the task's reward plus COEF × the geodesic progress
towards the centre per metre (:class:`~bimgame.learn.rewards.RewardSettings`; scores are always the
task's success).

The generalization gap is train − test success. Across seeds: means with percentile-bootstrap 95%
intervals (seeds resampled); per seed numbers are in the JSON. Runs are kept in ``--out`` (a rerun
reuses finished runs and their scores). Writes ``--results`` (default
benchmarks/results/generalization.json) and ``--figure`` (default docs/mazes/generalization.png):
train and test success against N, one panel per learner, CoinRun's figure.

Usage: python benchmarks/bench_generalization.py [--task STG1] [--obs state] [--steps 300000]
       [--seeds 3] [--num-mazes 1 10 100 1000 0] [--learners ppo a3c pretrain+ppo+keep]
       [--pretrain-data DATA] [--set NAME=VALUE ...] [--maze-frame board|marble]
       [--geodesic-reward COEF] [--gate-bearings] [--jobs 2]
       [--out runs/generalization]
       [--score-unfinished]   (score the last checkpoints of runs stopped early, e.g. for time)
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from bench_learners import _settings

from bimgame.experiments.methods import ppo_overrides
from bimgame.experiments.run_progress import completed_with_progress, dagger_progress, training_progress
from bimgame.experiments.statistics import mean_interval
from bimgame.learn.a3c import A3CConfig, train
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import load_run_network
from bimgame.learn.dagger import DAggerConfig, dagger
from bimgame.learn.encoders import MAZE_FRAMES
from bimgame.learn.maze_runs import maze_options
from bimgame.learn.ppo import PPOConfig, resolve_ppo_config, train_ppo
from bimgame.learn.pretrain import pretrain
from bimgame.learn.rewards import RewardSettings, run_reward
from bimgame.learn.runs import torch_threads
from bimgame.learn.supervised import PretrainConfig
from bimgame.util.files import atomic_write_bytes, read_json
from bimgame.util.images import save_png, subplots
from bimgame.util.processes import exit_when_parent_dies

ROOT = Path(__file__).resolve().parents[1]
#: ``pretrain+ppo+keep``: PPO from a π^s pre-trained on ``--pretrain-data`` (the registry's algorithm).
PRETRAINED = "pretrain+ppo+keep"
DAGGER = "dagger"
LEARNERS = ("ppo", "a3c", PRETRAINED, DAGGER)
SPLITS = ("train", "test")
MODES = ("greedy", "sampled")
#: Evaluation seed of the scores (the same starts for every run).
SCORE_SEED = 12345


def _label(num_mazes: int) -> str:
    return "unlimited" if num_mazes == 0 else str(num_mazes)


def _pi_s_dir(args: argparse.Namespace, seed: int) -> Path:
    """Where seed ``seed``'s π^s pre-trained on ``--pretrain-data`` is kept."""
    bearings = "-bearings" if args.gate_bearings else ""
    return args.out / "pi-s" / f"{args.task}-{args.obs}-{args.pretrain_data.name}{bearings}" / f"seed{seed}"


def _pretrained(args: argparse.Namespace, seed: int) -> tuple[Path, dict[str, float]]:
    """Seed ``seed``'s π^s (pre-trained on ``--pretrain-data`` unless already there, with one torch
    thread) and its scores on the splits, π^s alone (the dataset's mazes are its training mazes)."""
    path = _pi_s_dir(args, seed)
    with torch_threads(1):
        if not (path / "summary.json").is_file():
            if path.exists():  # an unfinished pre-training cannot resume: start it again
                raise SystemExit(f"{path} is an unfinished pre-training; remove it and run again")
            config = PretrainConfig(
                target="policy",
                task=args.task,
                obs=args.obs,
                seed=seed,
                eval_episodes=0,
                gate_bearings=args.gate_bearings,
            )
            pretrain(config, args.pretrain_data, path, progress=False)
        num_mazes = int((read_json(args.pretrain_data / "generation.json") or {}).get("num_mazes") or 0)
        scores, _ = _score(path, num_mazes, args.episodes)
    return path, scores


def _train(
    learner: str,
    run_dir: Path,
    *,
    task: str,
    obs: str,
    steps: int,
    seed: int,
    num_mazes: int,
    maze_frame: str,
    settings: dict[str, object],
    gate_bearings: bool = False,
    init: Path | None,
    reward: RewardSettings,
    dagger_budget: tuple[int, int] = (10, 32),
) -> float:
    """Train one run unless ``run_dir`` holds a finished one; the wall-clock seconds it took (0: reused).
    ``settings``: PPO settings beyond the algorithm's; ``init``: the π^s a ``pretrain+ppo+keep`` run starts from;
    ``dagger_budget``: a DAgger run's iterations and rollouts per iteration."""
    summary = read_json(run_dir / "summary.json")
    if summary is not None and summary.get("stopped") == "finished":
        return 0.0
    common = dict(task=task, obs=obs, steps=steps, seed=seed, eval_every=0, eval_episodes=20, num_mazes=num_mazes)
    if maze_frame != "board":  # runs stored before the setting are board-frame runs
        common["maze_frame"] = maze_frame
    if gate_bearings:
        common["gate_bearings"] = True
    start = time.perf_counter()
    resume = (run_dir / "config.json").is_file()
    if learner == DAGGER:
        iterations, episodes = dagger_budget
        learner_settings = PretrainConfig(
            task=task,
            obs=obs,
            seed=seed,
            aux_heads=False,
            asymmetric_critic=False,
            maze_frame=maze_frame,
            gate_bearings=gate_bearings,
        )
        config = DAggerConfig(
            learner=learner_settings, iterations=iterations, episodes_per_iteration=episodes, num_mazes=num_mazes
        )
        dagger(config, run_dir, resume=resume, progress=False)
    elif learner == "a3c":
        config = A3CConfig.from_flat(common, workers=2, envs_per_worker=16)
        reward, wrapper = run_reward(
            reward, run_dir, resume=resume, task=task, obs=obs, gamma=config.optimization.gamma
        )
        extra = {"reward": reward.to_dict()}
        train(config, run_dir, resume=resume, progress=False, env_wrapper=wrapper, extra_config=extra)
    elif learner == PRETRAINED:
        given = {**common, **ppo_overrides(PRETRAINED, steps, None), **settings}
        config = resolve_ppo_config(given, run_dir, resume=resume, init=None if resume else init)
        train_ppo(config, run_dir, resume=resume, init=None if resume else init, progress=False, reward=reward)
    else:
        ppo = PPOConfig.from_flat({**common, **settings})
        train_ppo(ppo, run_dir, resume=resume, progress=False, reward=reward)
    return time.perf_counter() - start


def _score(run_dir: Path, num_mazes: int, episodes: int) -> tuple[dict[str, float], int]:
    """Success of the run's network (its last checkpoint: the final one of a finished run) on its
    training mazes and on held-out test mazes, and the step of that checkpoint."""
    scores_file = run_dir / "generalization_scores.json"
    cached = read_json(scores_file)
    net, run, step = load_run_network(run_dir)
    if cached is not None and cached.get("episodes") == episodes and cached.get("step", step) == step:
        return cached["scores"], step
    seen = min(num_mazes, 100) if num_mazes else 100
    bearings = run.network.gate_bearings
    splits = {
        "train": (maze_options(num_mazes, 0, gate_bearings=bearings), [k % seen for k in range(episodes)]),
        "test": ({**maze_options(episodes, 0, gate_bearings=bearings), "maze_split": "test"}, list(range(episodes))),
    }
    scores = {}
    for split, (mazes, numbers) in splits.items():
        for mode in MODES:
            result = evaluate_network(
                net,
                task=run.task,
                obs_mode=run.network.obs,
                episodes=episodes,
                seed=SCORE_SEED,
                greedy=mode == "greedy",
                max_episode_steps=run.time_limit,
                mazes=mazes,
                maze_numbers=numbers,
            )
            scores[f"{split}_{mode}"] = float(np.mean(result.successes))
    atomic_write_bytes(
        scores_file, json.dumps({"episodes": episodes, "step": step, "scores": scores}, indent=2).encode()
    )
    return scores, step


def _run(
    learner: str, run_dir: Path, num_mazes: int, seed: int, args: argparse.Namespace
) -> tuple[float, dict[str, float], int]:
    """Train (unless finished, or with ``--score-unfinished``) and score one run with one torch
    thread: a job of ``--jobs``. Returns the training seconds, the scores and the scored step."""
    with torch_threads(1):
        seconds = 0.0
        if not args.score_unfinished:
            seconds = _train(
                learner,
                run_dir,
                task=args.task,
                obs=args.obs,
                steps=args.steps,
                seed=seed,
                num_mazes=num_mazes,
                maze_frame=args.maze_frame,
                settings=args.settings if learner == PRETRAINED else {},
                gate_bearings=args.gate_bearings,
                init=_pi_s_dir(args, seed) if learner == PRETRAINED else None,
                reward=RewardSettings(geodesic_coef=args.geodesic_reward),
                dagger_budget=(args.dagger_iterations, args.dagger_episodes),
            )
        return (seconds, *_score(run_dir, num_mazes, args.episodes))


def _progress(job: tuple[str, int, int, Path], args: argparse.Namespace) -> str | None:
    """The progress line of a running job of ``--jobs`` (learner, mazes, seed, run directory), from its logs."""
    learner, _, _, run_dir = job
    if learner == DAGGER:
        return dagger_progress(run_dir, args.dagger_iterations)
    return training_progress(run_dir, args.steps, learner=learner)


def _run_name(job: tuple[str, int, int, Path]) -> str:
    """How a progress line names a job: learner, training mazes and seed."""
    learner, num_mazes, seed, _ = job
    return f"{learner}, {num_mazes} mazes, seed {seed}"


def _aggregate(per_seed: list[dict[str, float]], rng: np.random.Generator) -> dict[str, Any]:
    """Means over seeds with bootstrap intervals, and the gap train − test per mode."""
    out: dict[str, Any] = {}
    keys = [f"{s}_{m}" for s in SPLITS for m in MODES]
    values = {key: np.array([scores[key] for scores in per_seed]) for key in keys}
    for mode in MODES:
        values[f"gap_{mode}"] = values[f"train_{mode}"] - values[f"test_{mode}"]
    for key, array in values.items():
        low, high = mean_interval(array, rng=rng)
        out[key] = {"mean": float(array.mean()), "interval": [low, high], "per_seed": array.tolist()}
    return out


def _plot(results: dict[str, Any], path: Path, title: str) -> Path:
    learners = [name for name in LEARNERS if name in results["learners"]]
    fig, axes = subplots(1, len(learners), figsize=(5.2 * len(learners), 4.0), squeeze=False, layout="constrained")
    for axis, learner in zip(axes[0], learners, strict=True):
        rows = results["learners"][learner]
        labels = list(rows)
        x = np.arange(len(labels))
        for split, colour in (("train", "tab:blue"), ("test", "tab:red")):
            for mode, style in (("sampled", "-"), ("greedy", "--")):
                stats = [rows[label][f"{split}_{mode}"] for label in labels]
                mean = np.array([s["mean"] for s in stats])
                low = np.array([s["interval"][0] for s in stats])
                high = np.array([s["interval"][1] for s in stats])
                axis.plot(x, 100 * mean, style, color=colour, marker="o", label=f"{split}, {mode}")
                if mode == "sampled":
                    axis.fill_between(x, 100 * low, 100 * high, color=colour, alpha=0.15)
                per_seed = [s["per_seed"] for s in stats]
                for i, seeds in enumerate(per_seed):
                    axis.scatter([i] * len(seeds), 100 * np.array(seeds), s=8, color=colour, alpha=0.4)
        if learner == PRETRAINED and "pi_s" in results:
            for split, colour in (("train", "tab:blue"), ("test", "tab:red")):
                level = 100 * results["pi_s"][f"{split}_sampled"]["mean"]
                axis.axhline(level, color=colour, linestyle=":", linewidth=1, label=f"π^s alone, {split}, sampled")
        axis.set_xticks(x, labels)
        axis.set_xlabel("training mazes N")
        axis.set_ylabel("success (%)")
        axis.set_ylim(-3, 103)
        axis.set_title(learner.upper(), fontsize=10)
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    return save_png(fig, path, dpi=110)


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    """The command line, checked: a bad flag value exits naming it and the allowed values."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="STG1")
    parser.add_argument("--obs", default="state", choices=("state", "pixels"))
    parser.add_argument("--steps", type=int, default=300_000, help="steps per run (default 300k)")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--num-mazes", type=int, nargs="+", default=[1, 10, 100, 1000, 0], help="0: unlimited")
    parser.add_argument("--learners", nargs="+", default=["ppo"], choices=LEARNERS)
    parser.add_argument("--episodes", type=int, default=100, help="scoring episodes per split and mode (default 100)")
    parser.add_argument(
        "--score-unfinished",
        action="store_true",
        help="train nothing: score each run's last checkpoint (runs stopped early; steps_scored says where)",
    )
    parser.add_argument(
        "--maze-frame",
        default="board",
        choices=MAZE_FRAMES,
        help="the frame the state network reads the maze encoding in (default board; see NetworkSettings.maze_frame)",
    )
    parser.add_argument(
        "--gate-bearings",
        action="store_true",
        help="state observations also hold each wall's nearest gate as seen from the marble "
        "(NetworkSettings.gate_bearings)",
    )
    parser.add_argument(
        "--pretrain-data",
        type=Path,
        default=None,
        help=f"{PRETRAINED}'s expert dataset on many training mazes (bimgame generate --num-mazes N)",
    )
    parser.add_argument(
        "--set", nargs="+", default=[], metavar="NAME=VALUE", help=f"PPO settings of the {PRETRAINED} runs"
    )
    parser.add_argument(
        "--geodesic-reward",
        type=float,
        default=None,
        metavar="COEF",
        help="train on the task's reward plus COEF x the geodesic progress (per metre); default: the task's reward",
    )
    parser.add_argument("--dagger-iterations", type=int, default=10, help="DAgger's iterations (default 10)")
    parser.add_argument("--dagger-episodes", type=int, default=32, help="DAgger's rollouts per iteration (default 32)")
    parser.add_argument("--jobs", type=int, default=1, help="runs trained at once, one process each (default 1)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "generalization")
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "generalization.json")
    parser.add_argument("--figure", type=Path, default=ROOT / "docs" / "mazes" / "generalization.png")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs takes a count >= 1, got {args.jobs}")
    if args.dagger_iterations < 1 or args.dagger_episodes < 1:
        parser.error(
            f"--dagger-iterations and --dagger-episodes take counts >= 1, got {args.dagger_iterations} "
            f"and {args.dagger_episodes}"
        )
    if any(n < 0 for n in args.num_mazes):
        parser.error(f"--num-mazes takes counts >= 0 (0: unlimited), got {args.num_mazes}")
    args.settings = _settings(args.set, parser)
    try:
        RewardSettings(geodesic_coef=args.geodesic_reward)
    except ValueError as error:
        parser.error(f"--geodesic-reward: {error}")
    if (PRETRAINED in args.learners) != (args.pretrain_data is not None):
        parser.error(f"--learners {PRETRAINED} and --pretrain-data go together (π^s is pre-trained on that dataset)")
    if args.pretrain_data is not None:
        manifest = read_json(args.pretrain_data / "generation.json") or {}
        if not (args.pretrain_data / "COMPLETE").is_file() or not manifest.get("num_mazes"):
            parser.error(
                f"--pretrain-data {args.pretrain_data} is not a finished dataset on many mazes "
                "(COMPLETE and num_mazes in generation.json): bimgame generate --num-mazes N"
            )
        args.pretrain_data = args.pretrain_data.absolute()
    args.out = args.out.absolute()
    return args


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    rng = np.random.default_rng(0)
    results: dict[str, Any] = {
        "task": args.task,
        "obs": args.obs,
        "steps": args.steps,
        "seeds": args.seeds,
        "episodes": args.episodes,
        "learners": {},
        "wall_seconds": {},
        "steps_scored": {},
    }
    frame = "" if args.maze_frame == "board" else f"-{args.maze_frame}"
    frame += "" if args.geodesic_reward is None else f"-geo{args.geodesic_reward:g}"
    frame += "-bearings" if args.gate_bearings else ""
    variant = "".join(f"-{key.replace('_', '-')}{value}" for key, value in sorted(args.settings.items()))
    data = "" if args.pretrain_data is None else f"-{args.pretrain_data.name}"

    def run_dir_of(learner: str, num_mazes: int, seed: int) -> Path:
        suffix = frame + (variant + data if learner == PRETRAINED else "")
        if learner == DAGGER:
            suffix = f"{frame}-it{args.dagger_iterations}x{args.dagger_episodes}"
        return args.out / f"{learner}-{args.task}-{args.obs}-n{_label(num_mazes)}{suffix}" / f"seed{seed}"

    jobs = [
        (learner, num_mazes, seed, run_dir_of(learner, num_mazes, seed))
        for learner in args.learners
        for num_mazes in args.num_mazes
        for seed in range(args.seeds)
    ]
    done: dict[Path, dict] = {}
    context = multiprocessing.get_context("spawn")
    if args.pretrain_data is not None:  # every π^s before any run that starts from it
        with ProcessPoolExecutor(args.jobs, mp_context=context, initializer=exit_when_parent_dies) as pool:
            pi_s = list(pool.map(_pretrained, [args] * args.seeds, range(args.seeds)))
        for seed, (_, scores) in enumerate(pi_s):
            shown = "  ".join(f"{k} {100 * v:3.0f}%" for k, v in scores.items())
            print(f"π^s seed {seed}: {shown}", flush=True)
        results["pi_s"] = {"data": str(args.pretrain_data), **_aggregate([s for _, s in pi_s], rng)}
    # Runs are independent: --jobs of them at once, each in its own process with one torch thread.
    with ProcessPoolExecutor(args.jobs, mp_context=context, initializer=exit_when_parent_dies) as pool:
        futures = {
            pool.submit(_run, learner, run_dir, n, seed, args): (learner, n, seed, run_dir)
            for learner, n, seed, run_dir in jobs
        }
        for future in completed_with_progress(futures, lambda key: _progress(key, args), name=_run_name):
            learner, num_mazes, seed, run_dir = futures[future]
            seconds, scores, step = future.result()
            if seconds:
                results["wall_seconds"][str(run_dir.relative_to(args.out))] = seconds
            results["steps_scored"][str(run_dir.relative_to(args.out))] = step
            done[run_dir] = scores
            shown = "  ".join(f"{k} {100 * v:3.0f}%" for k, v in scores.items())
            print(f"{learner} N={_label(num_mazes):>9} seed {seed}: {shown}", flush=True)
    for learner in args.learners:
        rows: dict[str, Any] = {}
        for num_mazes in args.num_mazes:
            per_seed = [done[run_dir] for ln, n, _, run_dir in jobs if ln == learner and n == num_mazes]
            rows[_label(num_mazes)] = _aggregate(per_seed, rng)
        results["learners"][learner] = rows
    results["maze_frame"] = args.maze_frame
    results["gate_bearings"] = args.gate_bearings
    results["ppo_settings"] = args.settings
    results["geodesic_reward"] = args.geodesic_reward
    if DAGGER in args.learners:
        results["dagger"] = {"iterations": args.dagger_iterations, "episodes_per_iteration": args.dagger_episodes}
    title = f"{args.task} from {args.obs}, {args.steps:,} steps, {args.seeds} seeds; {args.episodes} episodes per point"
    title += "; with gate bearings" if args.gate_bearings else ""
    figure = _plot(results, args.figure, title)
    atomic_write_bytes(args.results, json.dumps(results, indent=2).encode())
    print(f"wrote {args.results} and {figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
