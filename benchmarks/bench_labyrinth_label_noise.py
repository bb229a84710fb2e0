"""How consistent are the labyrinth expert's labels? The same state asked of fresh experts.

DAgger and behaviour cloning fit a network to the expert's action in each state. A random-shooting
expert's action is the first action of its best sampled sequence, and many sequences score alike,
so asking again from the same state gives another action: the learner is then fitted to the mean of
that spread, through its noise. This benchmark measures the spread.

States: ``--states`` physics states of the first ``--episodes`` episodes of an expert dataset
(``bimgame generate``), drawn from each episode's first ``--early-steps`` steps (the part of the
hard path where learned policies lose the marble), with the segment the env had there. For each
expert setting (``KxP``: K sequences per search, P searches averaged, :class:`LabyrinthMPCConfig`
``n_samples`` and ``n_plans``; ``--sampling`` hold or mppi) every state is asked of ``--repeats``
fresh experts (seeds ``1000·i + r``). With ``--warmup 0`` they have no remembered plan; with
``--warmup W`` each first plans along the dataset's W states before the asked one (its actions
there discarded), as DAgger's expert labels a rollout state after state, so the label is asked of an
expert with its plan (``keep_best``'s best sequence, MPPI's mean plan) in place. Reported per setting,
averaged over states:

- ``spread``: the standard deviation of the labels over the repeats, per action component (the
  components are tilt-rate fractions in [-1, 1]; 5 levels drawn uniformly spread 0.71);
- ``pair_agreement``: the share of pairs of repeats whose labels are within 0.25 in both components
  (the tolerance of ``bimgame pretrain``'s accuracy);
- ``mean_agreement``: the share of labels within 0.25 of the mean of the other repeats (how well the
  best possible clone, the conditional mean, would score on this metric);
- ``recorded_agreement``: the share within 0.25 of the action the dataset recorded there (an expert
  that had planned along the episode, its plan kept);
- ``ms_per_label``: planning time per label (inside ``act``, without building the expert) on this
  machine (loaded or not: ``load_average``).

Writes ``--results`` (default benchmarks/results/labyrinth_label_noise.json).

Usage: python benchmarks/bench_labyrinth_label_noise.py --expert-data DATA [--settings 16x1 64x1 16x2 16x4]
       [--sampling hold|mppi] [--warmup 0] [--episodes 20] [--states 40] [--early-steps 300]
       [--repeats 12] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_datasets import labyrinth_dataset_manifest, read_dataset_episode
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig
from bimgame.util.files import atomic_write_bytes

ROOT = Path(__file__).resolve().parents[1]
#: Two labels "agree" within this much in both components (bimgame pretrain's accuracy tolerance).
TOLERANCE = 0.25


def setting(text: str) -> tuple[int, int]:
    """``KxP`` → (K, P)."""
    try:
        k, p = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected KxP (e.g. 16x4: K = 16 sequences, P = 4 searches), got {text!r}"
        ) from None
    LabyrinthMPCConfig(n_samples=k, n_plans=p)  # refuses bad values by name
    return k, p


def draw_states(
    data: Path, episodes: int, count: int, early: int, rng: np.random.Generator, warmup: int = 0
) -> dict[str, Any]:
    """``count`` states spread evenly over the dataset's first ``episodes`` episodes, each drawn
    from the episode's steps ``warmup`` .. ``early`` - 1: their physics states, segments and recorded
    actions, the ``warmup`` states and segments before each, and the layout."""
    manifest = labyrinth_dataset_manifest(data)
    action_type = manifest["action_type"]
    chosen = [read_dataset_episode(data, manifest, i) for i in range(min(episodes, manifest["episodes"]))]
    if not chosen:
        raise ValueError(f"{data} holds no episodes")
    per_episode = -(-count // len(chosen))
    states, segments, actions, before = [], [], [], []
    for episode in chosen:
        steps = min(len(episode["actions"]), early) - warmup
        if steps <= 0:
            continue
        for t in warmup + rng.choice(steps, size=min(per_episode, steps), replace=False):
            states.append(episode["sim_states"][t])
            segments.append(int(episode["segments"][t]))
            actions.append(np.atleast_1d(np.asarray(episode["actions"][t], dtype=np.float64)))
            before.append([(episode["sim_states"][u], int(episode["segments"][u])) for u in range(t - warmup, t)])
    return {
        "layout": manifest["layout"],
        "action_type": action_type,
        "states": states[:count],
        "segments": segments[:count],
        "actions": actions[:count],
        "before": before[:count],
    }


def measure(drawn: dict[str, Any], k: int, p: int, repeats: int, sampling: str = "hold") -> dict[str, Any]:
    """The spread and agreement of ``repeats`` fresh experts' labels (K = k, P = p) per state, each
    expert first planning along the state's ``before`` states."""
    env = LabyrinthEnv(drawn["layout"], action_type=drawn["action_type"])
    config = LabyrinthMPCConfig(n_samples=k, n_plans=p, sampling=sampling)
    spread, pairs, means, recorded = [], [], [], []
    planning = 0.0  # seconds inside act(): building each fresh expert's model is not a label's cost
    off_diagonal = ~np.eye(repeats, dtype=bool)
    asked = zip(drawn["states"], drawn["segments"], drawn["actions"], drawn["before"], strict=True)
    for i, (state, segment, action, before) in enumerate(asked):
        labels = []
        for r in range(repeats):
            expert = LabyrinthMPC.for_env(env, config, rng=np.random.default_rng(1000 * i + r))
            for earlier, earlier_segment in before:
                expert.act(earlier, earlier_segment)
            started = time.perf_counter()
            label = expert.act(state, segment)
            planning += time.perf_counter() - started
            labels.append(np.atleast_1d(np.asarray(label, dtype=np.float64)))
            expert.close()
        stack = np.stack(labels)
        spread.append(float(stack.std(axis=0).mean()))
        apart = np.abs(stack[:, None] - stack[None]).max(axis=-1)
        pairs.append(float((apart[off_diagonal] <= TOLERANCE).mean()))
        others = (stack.sum(axis=0) - stack) / (repeats - 1)
        means.append(float((np.abs(others - stack).max(axis=-1) <= TOLERANCE).mean()))
        recorded.append(float((np.abs(stack - action).max(axis=-1) <= TOLERANCE).mean()))
    env.close()
    return {
        "n_samples": k,
        "n_plans": p,
        "sampling": sampling,
        "warmup": len(drawn["before"][0]),
        "spread": float(np.mean(spread)),
        "pair_agreement": float(np.mean(pairs)),
        "mean_agreement": float(np.mean(means)),
        "recorded_agreement": float(np.mean(recorded)),
        "ms_per_label": 1000 * planning / (len(drawn["states"]) * repeats),
        "load_average": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--expert-data", type=Path, required=True, help="a labyrinth expert dataset (bimgame generate)")
    parser.add_argument("--settings", type=setting, nargs="+", default=[(16, 1), (64, 1), (16, 2), (16, 4)])
    parser.add_argument("--sampling", choices=("hold", "mppi"), default="hold", help="the expert's sampling")
    parser.add_argument(
        "--warmup", type=int, default=0, help="recorded states each expert plans along before the asked one"
    )
    parser.add_argument("--episodes", type=int, default=20, help="episodes the states come from")
    parser.add_argument("--states", type=int, default=40)
    parser.add_argument("--early-steps", type=int, default=300, help="states from each episode's first N steps")
    parser.add_argument("--repeats", type=int, default=12, help="fresh experts asked per state (at least 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the states' draw")
    parser.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results" / "labyrinth_label_noise.json")
    args = parser.parse_args(argv)
    if args.repeats < 2:
        parser.error(f"--repeats must be at least 2, got {args.repeats}")
    if not 0 <= args.warmup < args.early_steps:
        parser.error(f"--warmup must be at least 0 and below --early-steps ({args.early_steps}), got {args.warmup}")
    rng = np.random.default_rng(args.seed)
    drawn = draw_states(args.expert_data, args.episodes, args.states, args.early_steps, rng, args.warmup)
    rows = []
    for k, p in args.settings:
        rows.append(measure(drawn, k, p, args.repeats, args.sampling))
        row = rows[-1]
        print(
            f"{args.sampling} K={k:3d} P={p} warm-up {args.warmup}: spread {row['spread']:.2f}  "
            f"pairs agree {row['pair_agreement']:.0%}  "
            f"within 0.25 of the others' mean {row['mean_agreement']:.0%}  of the recorded action "
            f"{row['recorded_agreement']:.0%}  ({row['ms_per_label']:.0f} ms a label)",
            flush=True,
        )
    results = {
        "expert_data": str(args.expert_data),
        "layout": drawn["layout"],
        "states": len(drawn["states"]),
        "episodes": args.episodes,
        "early_steps": args.early_steps,
        "repeats": args.repeats,
        "seed": args.seed,
        "tolerance": TOLERANCE,
        "rows": rows,
    }
    args.results.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(args.results, json.dumps(results, indent=2).encode())
    print(f"wrote {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
