"""The reference returns of the normalised score, stored with the package: per task, the mean return
of a uniformly random policy (score 0) and of the MPC expert with default settings (score 100), both
measured with the benchmark protocol (:mod:`bimgame.experiments.protocol`; measured anew with
``bimgame score --measure-references``). The expert's datasets carry them as Minari's
``ref_min_score`` / ``ref_max_score``, so ``minari.get_normalized_score`` gives the same numbers (as a
fraction: 0.85 where bimgame says 85)."""

from __future__ import annotations

import importlib.resources
import json

from bimgame.sim.tasks import parse_task

__all__ = ["REFERENCES_FILE", "reference_scores", "references_for", "normalised_score"]

REFERENCES_FILE = "reference_scores.json"


def reference_scores() -> dict[str, dict[str, float]]:
    """``{"STG1": {"random": R_random, "expert": R_expert, …}, …}``; empty before they are measured."""
    resource = importlib.resources.files("bimgame.expert").joinpath(REFERENCES_FILE)
    if not resource.is_file():
        return {}
    return json.loads(resource.read_text())["tasks"]


def references_for(task: str) -> tuple[float, float] | None:
    """(random, expert) mean returns of ``task``, or None if not measured."""
    entry = reference_scores().get(parse_task(task).value)
    return None if entry is None else (float(entry["random"]), float(entry["expert"]))


def normalised_score(task: str, mean_return: float) -> float:
    """``100 · (R − R_random) / (R_expert − R_random)``."""
    pair = references_for(task)
    if pair is None:
        raise ValueError(f"no reference scores for {task} (measure them with: bimgame score --measure-references)")
    low, high = pair
    return 100.0 * (mean_return - low) / (high - low)
