"""PPO's environment steps per second with its network on a GPU against the CPU, from state and from
pixels: whether a GPU pays for bimgame's PPO (16 environments stepped on the CPU in one process, the
network acting every step and updating every 16 × 128 steps).

With a GPU (``torch.cuda.is_available()``): four short PPO runs — state and pixels, each with the
setting ``device="cuda"`` and ``device="cpu"`` — of ``--steps`` steps each (no evaluation but the
final one of 1 episode), and their steps/s at steady state (the median of the second half of
updates.csv, as benchmarks/bench_learners.py measures it). ``device`` is one of PPO's flat settings
("cpu" | "cuda" | "auto"); a bimgame without it is reported as such and nothing is measured.

Without a GPU: prints "no GPU: nothing measured" and writes that, with the machine's torch version and
devices, and exits 0.

Writes ``--results`` (default benchmarks/results/gpu.json). Runs go to a temporary directory unless
``--out`` is given.

Usage: python benchmarks/bench_gpu.py [--task STG1] [--steps 20480] [--seed 0] [--out DIR] [--results PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path
from typing import Any

import torch

from bimgame.learn.ppo import PPOConfig, train_ppo
from bimgame.util.files import atomic_write_bytes

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_learners import steady_sps  # the benchmarks' one measure of steps/s

ROOT = Path(__file__).resolve().parents[1]
CASES = tuple((obs, device) for obs in ("state", "pixels") for device in ("cuda", "cpu"))


def machine() -> dict[str, Any]:
    """The torch build and the devices this machine has."""
    cuda = torch.cuda.is_available()
    return {
        "torch": torch.__version__,
        "torch_cuda": torch.version.cuda,
        "cuda_available": cuda,
        "gpus": [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())] if cuda else [],
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        # Other processes on the cores slow the CPU case (and torch's threads waiting for each other, both).
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def ppo_config(common: dict[str, Any], device: str) -> PPOConfig:
    """PPO's settings with ``device``; a ValueError saying so when this bimgame's PPO has no such setting."""
    try:
        return PPOConfig.from_flat(common, device=device)
    except ValueError as error:
        if "device" in str(error):
            raise ValueError(
                f"PPOConfig does not take the setting device={device!r} ({error}): this bimgame's PPO "
                f"cannot be put on a GPU"
            ) from error
        raise


def measure(args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Steps/s of each case (keyed ``OBS/DEVICE``), each a short PPO run in ``out``."""
    cases: dict[str, Any] = {}
    for obs, device in CASES:
        common = dict(task=args.task, obs=obs, steps=args.steps, seed=args.seed, eval_every=0, eval_episodes=1)
        config = ppo_config(common, device)
        run_dir = out / f"{args.task}-{obs}-{device}"
        print(f"PPO {args.task} {obs} on {device} -> {run_dir}", file=sys.stderr)
        result = train_ppo(config, run_dir, progress=False)
        cases[f"{obs}/{device}"] = {
            "steps_per_second": round(steady_sps(run_dir)),
            "steps": result.steps,
            "seconds": round(result.seconds, 1),
        }
    for obs in ("state", "pixels"):
        gpu, cpu = cases[f"{obs}/cuda"]["steps_per_second"], cases[f"{obs}/cpu"]["steps_per_second"]
        cases[f"{obs}/cuda"]["speedup_over_cpu"] = round(gpu / cpu, 2) if cpu else None
    return cases


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="STG1")
    parser.add_argument("--steps", type=int, default=20_480, help="steps of each run (default 20480: 10 rollouts)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="where the runs go (default: a temporary directory)")
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "gpu.json")
    args = parser.parse_args(argv)
    if args.steps < 1:
        parser.error(f"--steps must be at least 1, got {args.steps}")
    results: dict[str, Any] = {"task": args.task, "steps": args.steps, "machine": machine()}
    status = 0
    if not torch.cuda.is_available():
        results["measured"] = "no GPU: nothing measured"
        print("no GPU: nothing measured", file=sys.stderr)
    else:
        try:  # refused before anything runs when this bimgame's PPO has no device setting
            ppo_config({"task": args.task}, "cuda")
        except ValueError as error:
            results["measured"] = f"nothing measured: {error}"
            print(f"error: {error}", file=sys.stderr)
            status = 1
        else:
            if args.out is not None:
                results["cases"] = measure(args, args.out)
            else:
                with tempfile.TemporaryDirectory(prefix="bench-gpu-") as out:
                    results["cases"] = measure(args, Path(out))
            results["measured"] = "PPO steps/s on the GPU and on the CPU"
    atomic_write_bytes(args.results, (json.dumps(results, indent=1) + "\n").encode())
    print(json.dumps(results, indent=1))
    print(f"wrote {args.results}", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
