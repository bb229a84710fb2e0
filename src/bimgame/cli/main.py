"""The ``bimgame`` command line: ``bimgame <verb> [options]``.

Verbs:
  maze      draw the maze (walls, gates, channels, geodesic distance) to a PNG
  rollout   run episodes of a simple policy on a task, print a summary table, optionally a GIF
  demo         the Quick start's main job: a maze picture and a GIF of one episode
  expert-eval  success rate and trajectory lengths of the MPC expert, with the length histogram
  generate     expert trajectories as a Minari dataset (parallel, resumable, local or Ray)
  train        A3C with the paper's recurrent actor-critic (checkpoints, logs, resume)
  evaluate     success rate and episode length of a trained run, optionally a GIF
  curves       learning curves of a run (PNG)
  compare      learning curves of several groups of runs in one figure (PNG)
  pretrain     supervised pre-training on expert trajectories: the policy π^s or the value V̂
  dagger       DAgger with the MPC expert labelling the learner's states
  reproduce    the paper's experiments in one resumable command: dataset, pre-training, runs, report
  report       rebuild a reproduction's figures, tables and report.md from its saved results
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path

import numpy as np

from bimgame.cli.argtypes import positive_int

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    from bimgame.expert.policies import POLICIES
    from bimgame.sim.tasks import Task

    tasks = [t.value for t in Task]
    parser = argparse.ArgumentParser(prog="bimgame", description="The Ball-in-Maze Game on MuJoCo.")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    maze = verbs.add_parser("maze", help="draw the maze to a PNG")
    maze.add_argument("--out", type=Path, default=Path("maze.png"), help="PNG path (default maze.png)")
    maze.add_argument("--no-geodesic", action="store_true", help="do not shade the geodesic distance")

    rollout = verbs.add_parser("rollout", help="run episodes of a simple policy and summarise them")
    rollout.add_argument("--task", choices=tasks, default="STG1", type=str.upper)
    rollout.add_argument("--policy", choices=POLICIES, default="random")
    rollout.add_argument("--episodes", type=positive_int, default=10)
    rollout.add_argument("--seed", type=int, default=0)
    rollout.add_argument("--max-steps", type=positive_int, default=None,
                         help="time limit per episode (default: the task's registered limit)")
    rollout.add_argument("--n-marbles", type=positive_int, default=1)
    rollout.add_argument("--gif", type=Path, default=None, help="write the first episode as a GIF")

    demo = verbs.add_parser("demo", help="write a maze picture and a GIF of one episode")
    demo.add_argument("--out", type=Path, default=Path("out"), help="output directory (default out/)")
    demo.add_argument("--task", choices=tasks, default="FULL", type=str.upper)
    demo.add_argument("--policy", choices=POLICIES, default="expert")
    demo.add_argument("--seed", type=int, default=0)

    evaluate = verbs.add_parser("expert-eval", help="measure the MPC expert: success, lengths, histogram")
    evaluate.add_argument("--task", choices=tasks, default="FULL", type=str.upper)
    evaluate.add_argument("--episodes", type=positive_int, default=50)
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--workers", type=positive_int, default=None, help="processes (default: all cores)")
    evaluate.add_argument("--max-steps", type=positive_int, default=None,
                          help="time limit per episode (default: the task's registered limit)")
    add_mpc_arguments(evaluate)
    evaluate.add_argument("--out", type=Path, default=None,
                          help="directory for results.json and lengths.png (default: print only)")

    from bimgame.expert.datasets import add_generate_arguments

    generate = verbs.add_parser("generate", help="write expert trajectories as a Minari dataset")
    add_generate_arguments(generate)
    add_mpc_arguments(generate)

    from bimgame.cli.learn import add_dagger_arguments, add_pretrain_arguments
    from bimgame.cli.train import add_evaluate_arguments, add_train_arguments, step_count

    add_train_arguments(verbs.add_parser("train", help="train an A3C agent"))
    add_evaluate_arguments(verbs.add_parser("evaluate", help="evaluate a trained run"))
    add_pretrain_arguments(verbs.add_parser("pretrain", help="pre-train π^s (or V̂) on an expert dataset"))
    add_dagger_arguments(verbs.add_parser("dagger", help="DAgger with the MPC expert"))
    from bimgame.cli.reproduce import add_reproduce_arguments, add_report_arguments

    add_reproduce_arguments(verbs.add_parser("reproduce", help="run the paper's experiments (resumable)"))
    add_report_arguments(verbs.add_parser("report", help="rebuild a reproduction's figures, tables and report"))
    curves = verbs.add_parser("curves", help="plot a run's learning curves")
    curves.add_argument("run_dir", type=Path)
    curves.add_argument("--out", type=Path, default=None, help="PNG path (default RUN_DIR/curves.png)")
    compare = verbs.add_parser("compare", help="learning curves of groups of runs in one figure")
    compare.add_argument("groups", nargs="+", type=_run_group, metavar="LABEL=RUN[,RUN...]",
                         help="a label and the run directories averaged under it (e.g. seeds)")
    compare.add_argument("--out", type=Path, required=True, help="PNG path")
    compare.add_argument("--title", default="", help="figure title")
    compare.add_argument("--max-step", type=step_count, default=None, help="cut runs at this many steps (e.g. 1.2M)")
    return parser


def add_mpc_arguments(parser: argparse.ArgumentParser) -> None:
    """The MPC expert's flags (shared by expert-eval and generate)."""
    from bimgame.expert.mpc import PLANNING_REWARDS, SAMPLINGS, MPCConfig

    defaults = MPCConfig()
    parser.add_argument("--n-samples", "-K", type=positive_int, default=defaults.n_samples,
                        help=f"K, sequences per decision (default {defaults.n_samples})")
    parser.add_argument("--horizon", "-H", type=positive_int, default=defaults.horizon,
                        help=f"H, steps per sequence (default {defaults.horizon})")
    parser.add_argument("--sampling", choices=SAMPLINGS, default=defaults.sampling)
    parser.add_argument("--planning-reward", choices=PLANNING_REWARDS, default=defaults.reward)


def mpc_config_from(args) -> "MPCConfig":  # noqa: F821 (imported lazily)
    from bimgame.expert.mpc import MPCConfig

    return MPCConfig(n_samples=args.n_samples, horizon=args.horizon, sampling=args.sampling,
                     reward=args.planning_reward)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.verb == "maze":
            return _maze(args)
        if args.verb == "rollout":
            return _rollout(args)
        if args.verb == "demo":
            return _demo(args)
        if args.verb == "expert-eval":
            return _expert_eval(args)
        if args.verb == "generate":
            from bimgame.expert.datasets import run_generate

            return run_generate(args, mpc_config_from(args))
        if args.verb == "compare":
            from bimgame.learn.curves import plot_comparison

            path = plot_comparison(dict(args.groups), args.out, title=args.title, max_step=args.max_step)
            print(f"wrote {path}")
            return 0
        if args.verb == "curves":
            from bimgame.learn.curves import plot_run

            print(f"wrote {plot_run(args.run_dir, args.out)}")
            return 0
        if args.verb in ("pretrain", "dagger"):
            from bimgame.cli import learn as cli_learn

            return cli_learn.run_pretrain(args) if args.verb == "pretrain" else cli_learn.run_dagger(args)
        if args.verb in ("reproduce", "report"):
            from bimgame.cli import reproduce as cli_reproduce

            return cli_reproduce.run_reproduce(args) if args.verb == "reproduce" else cli_reproduce.run_report(args)
        if args.verb in ("train", "evaluate"):
            from bimgame.cli import train as cli_train

            return cli_train.run_train(args) if args.verb == "train" else cli_train.run_evaluate(args)
    except (ValueError, OSError) as error:
        print(f"bimgame {args.verb}: error: {error}", file=sys.stderr)
        return 2
    parser.error(f"unknown verb {args.verb!r}")
    return 2


def _run_group(text: str) -> tuple[str, list[Path]]:
    """``LABEL=RUN[,RUN...]`` → (label, run directories)."""
    label, sep, runs = text.partition("=")
    paths = [Path(r) for r in runs.split(",") if r]
    if not sep or not label or not paths:
        raise argparse.ArgumentTypeError(f"expected LABEL=RUN[,RUN...], got {text!r}")
    missing = [str(p) for p in paths if not p.is_dir()]
    if missing:
        raise argparse.ArgumentTypeError(f"not run directories: {', '.join(missing)}")
    return label, paths


# ---------------------------------------------------------------------- verbs
def _maze(args) -> int:
    from bimgame.sim.figures import draw_maze
    from bimgame.sim.maze import MazeSpec

    path = draw_maze(MazeSpec.merl(), args.out, geodesic=not args.no_geodesic)
    print(f"wrote {path}")
    return 0


def _rollout(args) -> int:
    from rich.console import Console
    from rich.table import Table

    results, frames = run_episodes(args.task, args.policy, args.episodes, seed=args.seed,
                                   max_steps=args.max_steps, n_marbles=args.n_marbles,
                                   record_first=args.gif is not None)
    console = Console()
    table = Table(title=f"{args.policy} policy on {args.task} ({args.episodes} episodes, seed {args.seed})")
    for column in ("episodes", "success", "mean return", "mean length", "median length", "steps/s"):
        table.add_column(column, justify="right")
    lengths = np.array([r["length"] for r in results])
    table.add_row(str(len(results)),
                  f"{np.mean([r['success'] for r in results]):.0%}",
                  f"{np.mean([r['return'] for r in results]):.2f}",
                  f"{lengths.mean():.1f}", f"{np.median(lengths):.0f}",
                  f"{lengths.sum() / max(sum(r['seconds'] for r in results), 1e-9):,.0f}")
    console.print(table)
    if args.gif is not None:
        console.print(f"wrote {write_gif(frames, args.gif)} ({len(frames)} frames)")
    return 0


def _demo(args) -> int:
    from bimgame.sim.figures import draw_maze
    from bimgame.sim.maze import MazeSpec

    maze_path = draw_maze(MazeSpec.merl(), args.out / "maze.png")
    print(f"wrote {maze_path}")
    results, frames = run_episodes(args.task, args.policy, 1, seed=args.seed, record_first=True)
    result = results[0]
    gif = write_gif(frames, args.out / "episode.gif")
    print(f"{args.policy} policy on {args.task}: {'solved' if result['success'] else 'not solved'} in "
          f"{result['length']} steps, return {result['return']:.0f}; wrote {gif}")
    return 0


def _expert_eval(args) -> int:
    from rich.console import Console
    from rich.table import Table

    from bimgame.expert.evaluation import evaluate_expert, plot_length_histogram, summarise, write_results

    config = mpc_config_from(args)
    start = time.perf_counter()
    results = evaluate_expert(args.task, args.episodes, config, seed=args.seed, workers=args.workers,
                              max_steps=args.max_steps)
    summary = summarise(results)
    summary["wall_seconds"] = time.perf_counter() - start
    table = Table(title=f"MPC expert on {args.task}: K={config.n_samples} H={config.horizon} "
                        f"{config.sampling} sampling, {config.reward} reward, seed {args.seed}")
    for column in ("episodes", "success", "median length (solved)", "90th pct", "max", "ms/decision", "wall s"):
        table.add_column(column, justify="right")
    fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    table.add_row(str(summary["episodes"]), f"{summary['success_rate']:.0%}", fmt(summary["median_length_solved"]),
                  fmt(summary["p90_length_solved"]), fmt(summary["max_length_solved"]),
                  f"{summary['ms_per_decision']:.1f}", f"{summary['wall_seconds']:.0f}")
    console = Console()
    console.print(table)
    if args.out is not None:
        write_results(results, summary, config, args.task, args.out / "results.json")
        png = plot_length_histogram(results, args.out / "lengths.png",
                                    title=f"MPC expert, {args.task}, K={config.n_samples}, H={config.horizon}")
        console.print(f"wrote {args.out / 'results.json'} and {png}")
    return 0


# ---------------------------------------------------------------------- helpers
def run_episodes(task: str, policy_name: str, episodes: int, *, seed: int = 0,
                 max_steps: int | None = None, n_marbles: int = 1, record_first: bool = False,
                 ) -> tuple[list[dict], list[np.ndarray]]:
    """Run ``episodes`` episodes of a named policy with a progress bar; returns per-episode
    results (return, length, success, seconds) and the first episode's RGB frames if asked."""
    import gymnasium as gym

    import bimgame  # noqa: F401  (registers the env ids)
    from bimgame.expert.episodes import episode_progress
    from bimgame.expert.policies import make_policy

    kwargs = {"obs_mode": "state", "n_marbles": n_marbles}
    if record_first:
        kwargs["render_mode"] = "rgb_array"
    if max_steps is not None:
        kwargs["max_episode_steps"] = max_steps
    env = gym.make(f"BiMGame/{task}-v0", **kwargs)
    rng = np.random.default_rng(seed)
    policy = make_policy(policy_name, env.unwrapped.maze, rng)
    results: list[dict] = []
    frames: list[np.ndarray] = []
    with episode_progress(True, f"{policy_name} on {task}", episodes, transient=True) as update:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            record = record_first and episode == 0
            if record:
                frames.append(env.render())
            total, length, start = 0.0, 0, time.perf_counter()
            while True:
                _, reward, terminated, truncated, info = env.step(policy(env))
                total += reward
                length += 1
                if record:
                    frames.append(env.render())
                if terminated or truncated:
                    break
            results.append({"return": total, "length": length, "success": bool(info["is_success"]),
                            "seconds": time.perf_counter() - start})
            update(results[-1]["success"])
    env.close()
    return results, frames


def write_gif(frames: list[np.ndarray], path: str | Path, fps: int = 30, max_frames: int = 600) -> Path:
    """Write RGB frames as an animated GIF (atomically), keeping at most ``max_frames`` by
    skipping frames evenly."""
    from PIL import Image

    from bimgame.util.files import atomic_write_bytes

    if not frames:
        raise ValueError("no frames to write")
    stride = max(1, int(np.ceil(len(frames) / max_frames)))
    images = [Image.fromarray(frame) for frame in frames[::stride]]
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:],
                   duration=int(round(1000 * stride / fps)), loop=0)
    return atomic_write_bytes(path, buffer.getvalue())


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
