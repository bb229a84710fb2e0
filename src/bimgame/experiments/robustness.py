"""How robust policies are to the ways a real board differs from the simulator: each policy — the MPC
expert, which plans with the nominal model, and trained runs — on the nominal board and on
domain-randomised boards (:mod:`bimgame.envs.randomization`), with success rates and episode
lengths per seed and a bootstrap interval over seeds.

The same episodes for every policy: episode i of a condition starts from
``reset(seed=episode_seed(seed, i))`` for the expert, and the batched evaluation of a network is
seeded with ``seed``; a randomised condition draws its parameters from the env's own generator,
so every policy meets the same boards.
"""

from __future__ import annotations

import csv
import dataclasses
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.envs.randomization import Randomization
from bimgame.experiments.statistics import mean_interval
from bimgame.expert.mpc import MPCConfig
from bimgame.expert.pool import expert_episodes
from bimgame.learn.actor import evaluate_network
from bimgame.learn.common import load_run_network
from bimgame.util.files import atomic_write_bytes
from bimgame.util.progress import ProgressBar

__all__ = ["EXPERT", "Measurement", "measure", "robustness_rows", "summary_rows", "write_robustness"]

#: The name of the MPC expert among the sources.
EXPERT = "expert"


@dataclasses.dataclass(frozen=True)
class Measurement:
    """One source (a run, or the expert with one seed) on one condition."""

    group: str
    source: str
    seed: int
    condition: str
    episodes: int
    success: float
    mean_length: float


def _expert_episodes(
    task: str, randomize: Randomization | None, episodes: int, seed: int, config: MPCConfig, workers: int
) -> tuple[float, float]:
    """Success rate and mean length of the MPC expert, which plans on the nominal model, on
    ``episodes`` episodes of the (randomised) env, on ``workers`` processes (the episodes do not
    depend on them)."""
    runs = [
        episode
        for _, episode, _ in expert_episodes(
            task, list(range(episodes)), seed, config, workers=workers, randomize=randomize
        )
    ]
    return float(np.mean([run["success"] for run in runs])), float(np.mean([len(run["actions"]) for run in runs]))


def measure(
    source: str,
    task: str,
    condition: str,
    randomize: Randomization | None,
    *,
    episodes: int,
    seed: int,
    group: str,
    sampled: bool = False,
    expert_config: MPCConfig | None = None,
    workers: int = 1,
) -> Measurement:
    """``source`` (``"expert"`` or a run directory) on ``episodes`` episodes of ``task`` under
    ``randomize`` (None: the nominal board); networks act greedily unless ``sampled``; the expert's
    episodes run on ``workers`` processes."""
    if source == EXPERT:
        success, length = _expert_episodes(task, randomize, episodes, seed, expert_config or MPCConfig(), workers)
    else:
        net, info, _ = load_run_network(source)
        result = evaluate_network(
            net,
            task=task,
            obs_mode=info.network.obs,
            episodes=episodes,
            seed=seed,
            greedy=not sampled,
            randomize=randomize,
        )
        success, length = float(np.mean(result.successes)), float(np.mean(result.lengths))
    return Measurement(group, source, seed, condition, episodes, success, length)


def robustness_rows(
    groups: dict[str, Sequence[str]],
    task: str,
    conditions: dict[str, Randomization | None],
    *,
    episodes: int,
    seed: int = 0,
    expert_seeds: int = 0,
    sampled: bool = False,
    progress: bool = False,
    workers: int = 1,
) -> list[Measurement]:
    """Every source of ``groups`` (label → run directories) and, with ``expert_seeds`` > 0, the expert
    (one source per seed, seeds ``seed`` … ``seed + expert_seeds − 1``, its episodes on ``workers``
    processes) on every condition."""
    sources = [(label, run, seed) for label, runs in groups.items() for run in runs]
    sources += [(EXPERT, EXPERT, seed + k) for k in range(expert_seeds)]
    rows = []
    with ProgressBar(f"robustness on {task}", len(sources) * len(conditions), enabled=progress) as bar:
        for label, source, source_seed in sources:
            for name, randomize in conditions.items():
                rows.append(
                    measure(
                        source,
                        task,
                        name,
                        randomize,
                        episodes=episodes,
                        seed=source_seed,
                        group=label,
                        sampled=sampled,
                        workers=workers,
                    )
                )
                bar.update(advance=1)
    return rows


def summary_rows(rows: list[Measurement], *, seed: int = 0) -> list[dict[str, Any]]:
    """Per group and condition: the per-source success rates and mean lengths, their means and a
    95% bootstrap interval of the mean success over sources (seeds)."""
    out = []
    keys = dict.fromkeys((r.group, r.condition) for r in rows)
    for group, condition in keys:
        chosen = [r for r in rows if r.group == group and r.condition == condition]
        success = np.array([r.success for r in chosen])
        low, high = (
            mean_interval(success, rng=np.random.default_rng(seed))
            if len(success) > 1
            else (float(success[0]), float(success[0]))
        )
        out.append(
            {
                "group": group,
                "condition": condition,
                "sources": len(chosen),
                "success_per_source": [round(float(s), 3) for s in success],
                "mean_success": float(success.mean()),
                "ci_low": low,
                "ci_high": high,
                "length_per_source": [round(r.mean_length, 1) for r in chosen],
                "mean_length": float(np.mean([r.mean_length for r in chosen])),
            }
        )
    return out


def write_robustness(rows: list[Measurement], out_dir: str | Path) -> tuple[Path, Path]:
    """``robustness.csv`` (one row per source and condition) and ``robustness.md`` (the summary
    table) in ``out_dir``, written atomically."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out_dir / "robustness.csv", _csv_text(rows).encode())
    atomic_write_bytes(out_dir / "robustness.md", _summary_table(rows).encode())
    return out_dir / "robustness.csv", out_dir / "robustness.md"


def _csv_text(rows: list[Measurement]) -> str:
    """``robustness.csv``: a header, then one line per measurement."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[f.name for f in dataclasses.fields(Measurement)])
    writer.writeheader()
    writer.writerows(dataclasses.asdict(r) for r in rows)
    return buffer.getvalue()


def _summary_table(rows: list[Measurement]) -> str:
    """``robustness.md``: a row per group, two columns per condition (success rates, mean length)."""
    conditions = list(dict.fromkeys(r.condition for r in rows))
    summary = summary_rows(rows)
    lines = [
        "| policy | "
        + " | ".join(f"{c}: success, per seed; mean [95% CI] | {c}: mean length" for c in conditions)
        + " |",
        "|---|" + "---|---|" * len(conditions),
    ]
    for group in dict.fromkeys(r.group for r in rows):
        cells = []
        for condition in conditions:
            entry = next(s for s in summary if s["group"] == group and s["condition"] == condition)
            per = ", ".join(f"{100 * s:.0f}" for s in entry["success_per_source"])
            cells.append(
                f"{per}; **{100 * entry['mean_success']:.0f}%** [{100 * entry['ci_low']:.0f}, "
                f"{100 * entry['ci_high']:.0f}]"
            )
            cells.append(f"{entry['mean_length']:.0f}")
        lines.append(f"| {group} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
