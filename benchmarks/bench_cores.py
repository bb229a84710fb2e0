"""How much a second process adds on this machine: PPO's rollout collection in one process alone, then
in two processes at once.

Every multi-process learner here (A3C's two workers, PPO's collector processes) is bounded by how
much work two processes get done together compared with one. Each process builds PPO's default
environments and acting network (``--task``, ``--obs``, ``--envs`` environments, one torch thread) and
collects ``--rollouts`` rollouts of 128 steps after one for warm-up; the steps/s of one process alone
and of each of two running together are printed and saved. A scaling of 2.0 means two independent
cores; less means the two share part of one (SMT siblings, a busy host).

Usage: python benchmarks/bench_cores.py [--task STG1] [--obs state] [--envs 16] [--rollouts 20]
       [--repeats 3] [--out benchmarks/results/cores.json]
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _collect_rate(task: str, obs: str, envs: int, rollouts: int, ready: object, go: object) -> float:
    """Steps/s of ``rollouts`` rollouts collected by one process (after a warm-up rollout; waits at
    ``ready``/``go`` so that processes measured together start together)."""
    import torch

    from bimgame.learn.learner_settings import policy_network
    from bimgame.learn.ppo.collectors import rollout_collector
    from bimgame.learn.ppo.settings import PPOConfig

    torch.set_num_threads(1)
    config = PPOConfig.from_flat(task=task, obs=obs, envs_per_worker=envs)
    net = policy_network(config)
    collector = rollout_collector(
        config, net, envs=envs, rank=0, step=0, on_episode=lambda episode: None, global_step=lambda: 0
    )
    n_steps = config.optimization.n_steps
    collector.collect(n_steps, 0)
    ready.wait()  # type: ignore[attr-defined]
    go.wait()  # type: ignore[attr-defined]
    started = time.perf_counter()
    for _ in range(rollouts):
        collector.collect(n_steps, 0)
    rate = rollouts * n_steps * envs / (time.perf_counter() - started)
    collector.close()
    return rate


def _measure(processes: int, args: argparse.Namespace) -> list[float]:
    """The steps/s of each of ``processes`` processes collecting at the same time."""
    context = multiprocessing.get_context("spawn")
    with context.Manager() as manager:
        ready, go = manager.Barrier(processes + 1), manager.Barrier(processes + 1)
        with context.Pool(processes) as pool:
            pending = [
                pool.apply_async(_collect_rate, (args.task, args.obs, args.envs, args.rollouts, ready, go))
                for _ in range(processes)
            ]
            ready.wait()
            go.wait()
            return [result.get() for result in pending]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="STG1")
    parser.add_argument("--obs", default="state", choices=("state", "pixels"))
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--rollouts", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3, help="alternations of one and two processes")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cores.json")
    args = parser.parse_args(argv)
    for name in ("envs", "rollouts", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    from bimgame.util.files import write_json

    alone, together = [], []
    for repeat in range(args.repeats):
        alone.append(_measure(1, args)[0])
        together.append(_measure(2, args))
        print(
            f"round {repeat + 1}: one process {alone[-1]:,.0f} steps/s; two at once "
            f"{together[-1][0]:,.0f} + {together[-1][1]:,.0f} = {sum(together[-1]):,.0f}",
            file=sys.stderr,
        )
    scaling = [sum(pair) / single for single, pair in zip(alone, together, strict=True)]
    result = {
        "task": args.task,
        "obs": args.obs,
        "envs": args.envs,
        "rollouts": args.rollouts,
        "one_process_sps": [round(value) for value in alone],
        "two_processes_sps": [[round(value) for value in pair] for pair in together],
        "scaling": [round(value, 3) for value in scaling],
        "median_scaling": round(float(np.median(scaling)), 3),
    }
    write_json(args.out, result)
    print(f"two processes do {result['median_scaling']:.2f}x the work of one (median); wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
