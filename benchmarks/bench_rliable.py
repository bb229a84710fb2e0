"""bimgame's bootstrap intervals against rliable's (Agarwal et al., "Deep RL at the Edge of the
Statistical Precipice", NeurIPS 2021) on every per-seed result the benchmarks saved.

bimgame computes its intervals with a few lines of numpy (:mod:`bimgame.experiments.statistics`:
a stratified percentile bootstrap over seeds). rliable implements the same resampling and adds the
interquartile mean (IQM) and performance profiles. This script answers whether rliable would give
the same or better statistics here: for every ``{"per_seed": [...], "interval": [...]}`` entry of
``benchmarks/results/*.json`` (at least two seeds) it computes the mean's 95% interval both ways
with the same number of resamples, and rliable's IQM with its interval, and reports the largest
difference between the two mean intervals relative to the spread of the seeds.

rliable is not a dependency of bimgame; install it into the environment first. rliable 1.2.0 needs
``arch``, whose releases up to 7.2 fail to import beside pandas 3, so pin pandas below 3:
``pip install rliable==1.2.0 "pandas<3"``.

Writes ``--out`` (default benchmarks/results/rliable_comparison.json).

Usage: python benchmarks/bench_rliable.py [--resamples 50000]
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bimgame.experiments.statistics import mean_interval
from bimgame.util.files import atomic_write_bytes

ROOT = Path(__file__).resolve().parents[1]


def _entries(value: Any, path: str) -> Iterator[tuple[str, list[float]]]:
    """(path, per-seed values) of every entry with two or more numeric seeds, depth first."""
    if isinstance(value, dict):
        seeds = value.get("per_seed")
        if isinstance(seeds, list) and len(seeds) >= 2 and all(isinstance(v, (int, float)) for v in seeds):
            if "interval" in value:
                yield path, [float(v) for v in seeds]
        for key, item in value.items():
            yield from _entries(item, f"{path}.{key}" if path else str(key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _entries(item, f"{path}[{index}]")


def _rliable(seeds: np.ndarray, resamples: int, seed: int) -> dict[str, list[float]]:
    """rliable's percentile intervals of the mean and the IQM: one task, the seeds as its runs."""
    from rliable import library, metrics  # noqa: PLC0415 — optional: only this benchmark needs it

    scores = {"x": seeds.reshape(-1, 1)}
    out = {}
    for name, statistic in (("mean", metrics.aggregate_mean), ("iqm", metrics.aggregate_iqm)):
        point, interval = library.get_interval_estimates(
            scores,
            lambda s, f=statistic: np.array([f(s)]),
            reps=resamples,
            random_state=np.random.RandomState(seed),
        )
        out[name] = [float(point["x"][0]), *map(float, interval["x"][:, 0])]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resamples", type=int, default=50_000)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "rliable_comparison.json")
    args = parser.parse_args(argv)
    rows = []
    for file in sorted((ROOT / "benchmarks" / "results").glob("*.json")):
        if file.resolve() == args.out.resolve():
            continue
        for path, seeds in _entries(json.loads(file.read_text()), ""):
            values = np.array(seeds)
            ours = mean_interval(values, resamples=args.resamples, rng=np.random.default_rng(0))
            theirs = _rliable(values, args.resamples, 0)
            spread = float(values.max() - values.min())
            difference = max(abs(ours[0] - theirs["mean"][1]), abs(ours[1] - theirs["mean"][2]))
            rows.append(
                {
                    "file": file.name,
                    "entry": path,
                    "per_seed": seeds,
                    "bimgame_mean_interval": list(ours),
                    "rliable_mean": theirs["mean"],
                    "rliable_iqm": theirs["iqm"],
                    "difference_relative_to_spread": difference / spread if spread > 0 else 0.0,
                }
            )
    differences = np.array([row["difference_relative_to_spread"] for row in rows])
    iqm_differs = sum(abs(row["rliable_iqm"][0] - float(np.mean(row["per_seed"]))) > 1e-12 for row in rows)
    summary = {
        "entries": len(rows),
        "resamples": args.resamples,
        "seeds_per_entry": sorted({len(row["per_seed"]) for row in rows}),
        "largest_difference_relative_to_spread": float(differences.max()) if len(rows) else None,
        "median_difference_relative_to_spread": float(np.median(differences)) if len(rows) else None,
        "entries_whose_iqm_differs_from_the_mean": int(iqm_differs),
    }
    atomic_write_bytes(args.out, json.dumps({"summary": summary, "rows": rows}, indent=2).encode())
    print(json.dumps(summary, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
