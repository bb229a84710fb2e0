"""What the Ray backend of ``bimgame reproduce`` costs: the same tiny grid on the local backend and
on Ray's multi-node test cluster on this machine (a head without CPUs and two one-CPU nodes,
``ray.cluster_utils.Cluster``), wall time side by side, with the cluster's start-up timed apart.

The grid: STG1, state observations, 2 seeds; the dataset (8 expert episodes), π^s and V̂ per seed,
A3C, pre-train + A3C + value reward (20k steps, one worker) and DAgger (2 iterations) — 11 pieces.
On one machine the cluster cannot be faster than the 2 cores it shares; the figure is the price of
the tasks, archives and object store, and what two pieces side by side win back. Results are
checked equal between the backends (the runs' episode logs byte for byte).

**A node that dies.** Then one A3C piece (``--fault-steps``, a checkpoint every tenth of it) on the
same cluster, twice: undisturbed, and with the node running it removed (``remove_node``, not
gracefully) once the run has shipped a checkpoint from past the middle of the run. The retried
task continues from that checkpoint on the other node; the figure is the wall time lost to the
fault, against the half of the run that a restart from scratch would have repeated.

Usage: ``python benchmarks/bench_cluster.py [--steps N] [--fault-steps N]``; writes
``benchmarks/results/cluster.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import threading
import time
from pathlib import Path

from bimgame.experiments.budgets import (
    A3CBudget,
    Budget,
    DaggerBudget,
    DatasetBudget,
    NetworkBudget,
    PretrainBudget,
    ValueBudget,
)
from bimgame.experiments.cluster import PIECE_MARKER, WORK_ROOT_ENV, local_cluster
from bimgame.experiments.reproduce import reproduce
from bimgame.util.files import atomic_write_bytes

RESULTS = Path(__file__).parent / "results" / "cluster.json"


def tiny_grid(steps: int) -> Budget:
    """The benchmark's grid (see the module notes)."""
    return Budget(name="bench-cluster", tasks=("STG1",), algorithms=("a3c", "pretrain+a3c+value", "dagger"), seeds=2,
                  obs="state", network=NetworkBudget(hidden=32, features=32),
                  a3c=A3CBudget(steps={"STG1": steps}, workers=1, envs_per_worker=8, eval_every=0, eval_episodes=4,
                                checkpoint_every=5_000),
                  dataset=DatasetBudget(task="STG1", episodes=8, workers=1),
                  pretrain=PretrainBudget(epochs=4, patience=2, eval_episodes=4),
                  value=ValueBudget(epochs=4, patience=2),
                  dagger=DaggerBudget(iterations=2, episodes=3, epochs=2, eval_episodes=4))


def _node_past_the_middle(work_root: Path, piece_id: str, shipments: int, timeout: float) -> str | None:
    """The id of the node whose task for ``piece_id`` has shipped ``shipments`` checkpoints."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for marker in work_root.glob(f"*/{PIECE_MARKER}"):
            try:
                info = json.loads(marker.read_text())
            except (OSError, ValueError):
                continue  # being replaced
            if info.get("piece") == piece_id and info.get("shipped", 0) >= shipments:
                return info["node_id"]
        time.sleep(0.1)
    return None


def fault(cluster, root: Path, work_root: Path, budget: Budget) -> dict:
    """One A3C piece undisturbed, then again with its node removed past the middle (see the notes)."""
    piece = "runs/STG1/a3c/seed0"
    started = time.monotonic()
    assert reproduce(root / "undisturbed", budget, progress=False, backend="ray").complete
    undisturbed = time.monotonic() - started
    # The step-0 checkpoint is the first shipment; one more per tenth of the run.
    shipments = 1 + 6
    outcome: dict = {}
    started = time.monotonic()
    driver = threading.Thread(target=lambda: outcome.update(
        result=reproduce(root / "faulted", budget, progress=False, backend="ray")))
    driver.start()
    victim = _node_past_the_middle(work_root, piece, shipments, timeout=600)
    killed_after = time.monotonic() - started
    assert victim is not None, "the piece never shipped its checkpoints"
    cluster.remove_node(next(n for n in cluster.worker_nodes if n.node_id == victim), allow_graceful=False)
    driver.join()
    faulted = time.monotonic() - started
    entry = json.loads((root / "faulted" / "status.json").read_text())["pieces"][piece]
    assert outcome["result"].complete and entry["note"].startswith("resumed"), entry
    return {"a3c_steps": budget.steps_for("STG1"), "checkpoint_every": budget.a3c.checkpoint_every,
            "undisturbed_seconds": round(undisturbed, 1), "node_removed_after_seconds": round(killed_after, 1),
            "with_node_death_seconds": round(faulted, 1), "lost_seconds": round(faulted - undisturbed, 1),
            "note": entry["note"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20_000, help="A3C steps per run (default 20k)")
    parser.add_argument("--fault-steps", type=int, default=100_000,
                        help="A3C steps of the run whose node dies (default 100k)")
    args = parser.parse_args()
    import ray

    budget = tiny_grid(args.steps)
    fault_budget = budget.replace(algorithms=("a3c",), seeds=1,
                                  a3c={"steps": {"STG1": args.fault_steps},
                                       "checkpoint_every": max(1, args.fault_steps // 10)})
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        os.environ[WORK_ROOT_ENV] = str(root / "node-work")  # the nodes inherit it: where their tasks work
        started = time.monotonic()
        local = reproduce(root / "local", budget, progress=False)
        local_seconds = time.monotonic() - started

        started = time.monotonic()
        with local_cluster(nodes=2, cpus_per_node=1) as cluster:
            startup_seconds = time.monotonic() - started
            started = time.monotonic()
            on_ray = reproduce(root / "ray", budget, progress=False, backend="ray")
            ray_seconds = time.monotonic() - started
            node_death = fault(cluster, root, root / "node-work", fault_budget)
        assert local.complete and on_ray.complete, (local, on_ray)
        same = all((root / "local" / piece / "episodes.csv").read_bytes()
                   == (root / "ray" / piece / "episodes.csv").read_bytes()
                   for piece in local.computed if piece.startswith("runs/") and "dagger" not in piece)
        piece_seconds = {backend: json.loads((root / backend / "status.json").read_text())["pieces"]
                         for backend in ("local", "ray")}
    busy = {backend: round(sum(e.get("seconds", 0.0) for e in entries.values()), 1)
            for backend, entries in piece_seconds.items()}
    result = {
        "grid": {"pieces": len(local.computed), "a3c_steps": args.steps, "budget": budget.to_dict()},
        "local_seconds": round(local_seconds, 1),
        "ray_2_nodes_seconds": round(ray_seconds, 1),
        "ray_cluster_startup_seconds": round(startup_seconds, 1),
        "ratio_ray_to_local": round(ray_seconds / local_seconds, 2),
        "sum_of_piece_seconds": busy,
        "same_episode_logs": same,
        "node_death": node_death,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "ray": ray.__version__},
        "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"tiny grid, {result['grid']['pieces']} pieces: local {local_seconds:.1f} s; 2-node Ray test cluster "
          f"{ray_seconds:.1f} s ({result['ratio_ray_to_local']}×), plus {startup_seconds:.1f} s to start the "
          f"cluster; summed piece times local {busy['local']} s, Ray {busy['ray']} s; same episode logs: {same}")
    print(f"one A3C run of {node_death['a3c_steps']} steps: {node_death['undisturbed_seconds']} s undisturbed, "
          f"{node_death['with_node_death_seconds']} s with its node removed after "
          f"{node_death['node_removed_after_seconds']} s ({node_death['note']})")
    atomic_write_bytes(RESULTS, (json.dumps(result, indent=2) + "\n").encode())
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
