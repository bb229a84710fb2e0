"""A3C throughput against the network's own limit, measured in the same run.

For state observations and for pixels in three settings — the paper's network in float32 and in
bfloat16 (``--precision bf16``), and the default pixel network (bf16, auxiliary heads, asymmetric
critic):

- **network-only limit**: ``workers`` processes run exactly the A3C worker's network work — n_steps
  batched acting forwards, the segment's forward+backward, gradient clipping and the shared
  optimiser step on shared weights — on recorded observations, with no environment. Samples per
  second over all processes.
- **A3C**: ``bimgame.learn.a3c.train`` with the same settings; environment steps per second at steady
  state (from the run's updates.csv, so process start-up is excluded).

The ratio A3C / network-only says how much the environment costs on top of the network. Writes
benchmarks/results/a3c.json.

Usage: python benchmarks/bench_a3c.py [--seconds 60] [--workers 2] [--envs-per-worker 16] [--settings NAME ...]
"""

from __future__ import annotations

import argparse
import csv
import json
import multiprocessing as mp
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from bimgame.envs.vector import BallInMazeVectorEnv
from bimgame.learn.a3c import A3CConfig, apply_update, make_optimizer, network_for, shared_optimizer_state, train
from bimgame.learn.actor import RecurrentActor
from bimgame.learn.nets import LSTMState
from bimgame.learn.rollout import Segment
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results"


#: The measured settings: name → A3C settings beyond the observation mode.
SETTINGS = {
    "pixels-fp32-papernet": dict(obs="pixels", precision="fp32"),
    "pixels-bf16-papernet": dict(obs="pixels", precision="bf16"),
    "pixels-bf16-privileged": dict(obs="pixels", precision="bf16", aux_heads=True, asymmetric_critic=True),
    "state": dict(obs="state"),
}


def _recorded_inputs(config: A3CConfig) -> dict[str, torch.Tensor]:
    """A segment's worth of real observations, tilts and (for privileged networks) states, so the
    network sees realistic frames."""
    network, batch = config.network, config.schedule.envs_per_worker
    env = BallInMazeVectorEnv(batch, task=config.task, obs_mode=network.obs, nthread=1, state_info=network.privileged)
    obs, info = env.reset(seed=0)
    recorded: dict[str, list] = {"obs": [], "tilt": [], "privileged": []}
    rng = np.random.default_rng(0)
    for _ in range(config.optimization.n_steps + 1):
        recorded["obs"].append(torch.as_tensor(obs))
        recorded["tilt"].append(torch.as_tensor(info["tilt"], dtype=torch.float32))
        if network.privileged:
            recorded["privileged"].append(torch.as_tensor(info["state"]))
        obs, _, _, _, info = env.step(rng.integers(0, 5, batch))
    return {k: torch.stack(v) for k, v in recorded.items() if v}


def _network_worker(config: A3CConfig, shared, optimizer_state, seconds: float, results) -> None:
    torch.set_num_threads(1)
    inputs = _recorded_inputs(config)
    frames, tilts = inputs["obs"], inputs["tilt"]
    local = network_for(config)
    optimizer = make_optimizer(config, shared)
    shared_params = list(shared.parameters())
    for param, state in zip(shared_params, optimizer_state):
        optimizer.state[param] = state
    n, batch = config.optimization.n_steps, config.schedule.envs_per_worker
    actor = RecurrentActor(local, batch, generator=torch.Generator().manual_seed(0))
    samples, start, updates = 0, None, 0
    while True:
        if updates == 1:  # the first update warms up; time from the second
            start, samples = time.perf_counter(), 0
        if start is not None and time.perf_counter() - start >= seconds:
            break
        local.load_state_dict(shared.state_dict())
        h0, c0 = actor.state
        seg = {k: [] for k in ("prev_action", "prev_reward", "starts", "actions")}
        for t in range(n):
            seg["prev_action"].append(actor.prev_action)
            seg["prev_reward"].append(actor.prev_reward)
            seg["starts"].append(actor.starts)
            actions, _, _ = actor.act(frames[t], tilts[t])
            seg["actions"].append(actions)
            actor.observe(actions, np.zeros(batch), np.zeros(batch, dtype=bool))
        seg["prev_action"].append(actor.prev_action)
        seg["prev_reward"].append(actor.prev_reward)
        seg["starts"].append(actor.starts)
        stacked = {k: torch.stack(v) for k, v in seg.items()}
        segment = Segment(**stacked, obs=inputs["obs"], tilt=inputs["tilt"] if config.network.tilt_input else None,
                          privileged=inputs.get("privileged"), rewards=torch.zeros(n, batch),
                          ends=torch.zeros(n, batch, dtype=torch.bool), initial_state=LSTMState(h0, c0))
        apply_update(local, shared_params, optimizer, segment, config)
        samples += n * batch
        updates += 1
    results.put(samples / (time.perf_counter() - start))


def network_only_sps(config: A3CConfig, seconds: float) -> float:
    torch.set_num_threads(1)
    shared = network_for(config)
    shared.share_memory()
    optimizer_state = shared_optimizer_state(make_optimizer(config, shared))
    context = mp.get_context("spawn")
    results = context.Queue()
    processes = [context.Process(target=_network_worker, args=(config, shared, optimizer_state, seconds, results))
                 for _ in range(config.schedule.workers)]
    for process in processes:
        process.start()
    rates = [results.get() for _ in processes]
    for process in processes:
        process.join()
    return float(sum(rates))


def a3c_sps(config: A3CConfig) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        train(config, Path(tmp) / "run", progress=False)
        with open(Path(tmp) / "run" / "updates.csv", newline="") as handle:
            rows = list(csv.DictReader(handle))
    # Steady state: from the first loss report after start-up to the last.
    rows = [r for r in rows if r["seconds"]]
    first, last = rows[len(rows) // 5], rows[-1]
    return (float(last["step"]) - float(first["step"])) / (float(last["seconds"]) - float(first["seconds"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="measuring time per setting")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--envs-per-worker", type=int, default=16)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    args = parser.parse_args()
    results = {"workers": args.workers, "envs_per_worker": args.envs_per_worker, "cpu_threads_per_worker": 1,
               "settings": []}
    for name in args.settings:
        probe = A3CConfig.from_flat(task="STG1", workers=args.workers, envs_per_worker=args.envs_per_worker, steps=1,
                                    eval_every=0, **SETTINGS[name])
        limit = network_only_sps(probe, args.seconds)
        steps = int(max(limit, 500) * args.seconds * 1.2)
        config = probe.with_flat(steps=steps, checkpoint_every=10 * steps, log_every=2_000)
        sps = a3c_sps(config)
        row = {"setting": name, **SETTINGS[name], "hidden": config.network.hidden, "features": config.network.features,
               "network_only_sps": limit, "a3c_sps": sps, "ratio": sps / limit}
        results["settings"].append(row)
        print(f"{name:>24}: A3C {sps:,.0f} env steps/s; network alone {limit:,.0f} samples/s; ratio {sps / limit:.2f}",
              flush=True)
    RESULTS.mkdir(exist_ok=True)
    atomic_write_bytes(RESULTS / "a3c.json", (json.dumps(results, indent=2) + "\n").encode())
    print(f"wrote {RESULTS / 'a3c.json'}", file=sys.stderr)


if __name__ == "__main__":
    main()
