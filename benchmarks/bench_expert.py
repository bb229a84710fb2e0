"""The MPC expert: how good (success, lengths) and how fast (time per decision against its floor).

Quality: success rate and trajectory lengths over N seeded episodes per task and setting (planning
reward, sampling, K, H), plus the Fig. 1b histogram for the default setting on FULL.

Speed: time per decision on 1 and 2 threads against the floor K·H·substeps ÷ the engine's own
rollout throughput (one ``mujoco.rollout`` call of K sequences × H·substeps physics steps, no Python
in between), measured from the same states (taken along an expert trajectory); and expert
trajectories per minute with all cores.

Usage: ``python benchmarks/bench_expert.py [--episodes 50] [--skip-quality] [--skip-speed]``;
writes ``benchmarks/results/expert.json`` and ``benchmarks/results/expert_lengths_full.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from bimgame.expert.evaluation import evaluate_expert, plot_length_histogram, summarise
from bimgame.expert.mpc import MPCConfig, RandomShootingMPC, run_expert_episode
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results"

SETTINGS = {
    "paper: radial, uniform, K=10 H=20": MPCConfig(reward="radial", sampling="uniform"),
    "default: radial, hold, K=10 H=20": MPCConfig(),
    "geodesic, hold, K=10 H=20": MPCConfig(reward="geodesic"),
    "radial, hold, K=10 H=10": MPCConfig(horizon=10),
    "radial, hold, K=5 H=20": MPCConfig(n_samples=5),
}


def quality(episodes: int, tasks: list[str], result: dict, path: Path) -> dict:
    table: dict = result.setdefault("quality", {})
    for name, config in SETTINGS.items():
        for task in tasks:
            start = time.perf_counter()
            results = evaluate_expert(task, episodes, config, seed=0)
            summary = summarise(results)
            summary["wall_seconds"] = time.perf_counter() - start
            summary["trajectories_per_minute"] = 60 * episodes / summary["wall_seconds"]
            table.setdefault(name, {})[task] = summary
            print(f"{name:38s} {task:5s} success {summary['success_rate']:5.0%}  median "
                  f"{summary['median_length_solved']}  p90 {summary['p90_length_solved']}  "
                  f"{summary['trajectories_per_minute']:.1f} traj/min", flush=True)
            if name.startswith("default") and task == "FULL":
                plot_length_histogram(results, RESULTS / "expert_lengths_full.png",
                                      title="MPC expert on FULL (K=10, H=20, radial, hold)")
                table[name][task]["lengths_solved"] = [r.length for r in results if r.success]
            result["episodes"] = episodes
            atomic_write_bytes(path, json.dumps(result, indent=1).encode())  # after every row
    return table


def speed(config: MPCConfig, decisions: int = 60) -> dict:
    """Per-decision time of the expert vs. the floor, from states along an expert trajectory."""
    episode = run_expert_episode("FULL", 123, config, max_steps=decisions)
    states = episode["sim_states"][:decisions]
    out = {}
    for nthread in (1, 2):
        expert = RandomShootingMPC(config=dataclasses.replace(config, nthread=nthread), rng=np.random.default_rng(0))
        sequences = [expert.sample_sequences() for _ in states]
        model = expert.sim.model
        datas = [mujoco.MjData(model) for _ in range(nthread)]
        pool = mj_rollout.Rollout(nthread=nthread) if nthread > 1 else None
        substeps = expert.sim.substeps

        def engine() -> float:
            """One rollout call per decision, controls precomputed: the engine's own limit."""
            total = 0.0
            for state, seq in zip(states, sequences):
                rates = np.repeat(np.zeros((config.n_samples, config.horizon, 4)), substeps, axis=1)
                # Constant zero-rate control costs the engine the same as any other control.
                init = np.tile(state, (config.n_samples, 1))
                begin = time.perf_counter()
                if pool is None:
                    mj_rollout.rollout(model, datas[0], init, rates, initial_warmstart=np.zeros((config.n_samples, model.nv)))
                else:
                    pool.rollout(model, datas, init, rates, initial_warmstart=np.zeros((config.n_samples, model.nv)),
                                 chunk_size=max(1, -(-config.n_samples // nthread)))
                total += time.perf_counter() - begin
            return total / len(states)

        def expert_decisions() -> float:
            begin = time.perf_counter()
            for state in states:
                expert.plan(state)
            return (time.perf_counter() - begin) / len(states)

        floor = min(engine() for _ in range(3))
        per_decision = min(expert_decisions() for _ in range(3))
        out[f"{nthread} thread(s)"] = {
            "ms_per_decision": 1e3 * per_decision, "floor_ms": 1e3 * floor, "ratio_to_floor": per_decision / floor,
            "engine_physics_steps_per_s": config.n_samples * config.horizon * substeps / floor,
        }
        print(f"speed, {nthread} thread(s): {1e3 * per_decision:.1f} ms/decision, floor {1e3 * floor:.1f} ms, "
              f"ratio {per_decision / floor:.2f}", flush=True)
        if pool is not None:
            pool.close()
        expert.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--tasks", nargs="+", default=["FULL", "STG1", "STG2"])
    parser.add_argument("--skip-quality", action="store_true")
    parser.add_argument("--skip-speed", action="store_true")
    args = parser.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / "expert.json"
    result = json.loads(path.read_text()) if path.exists() else {}
    if not args.skip_speed:
        result["speed"] = speed(MPCConfig())
    if not args.skip_quality:
        result["quality"] = {}
        quality(args.episodes, args.tasks, result, path)
    result["time"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    atomic_write_bytes(path, json.dumps(result, indent=1).encode())
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
