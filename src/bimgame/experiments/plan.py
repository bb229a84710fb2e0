"""A reproduction directory's bookkeeping: ``plan.json`` (the budget and every piece with its cost
estimate), ``status.json`` (each piece's state, wall time and how often it was computed), and
whether a piece is finished.

**Resuming.** Whether a piece is finished is decided from its own outputs (:func:`piece_done`, by
its kind: :mod:`bimgame.experiments.kinds`), never from ``status.json`` alone. Finished pieces are
skipped; an unfinished A3C, PPO or DAgger run is resumed from its last checkpoint (an A3C run stopped
in its final evaluation, whose checkpoint holds all its steps, then only evaluates and writes its
summary), an unfinished dataset from its saved episodes; an unfinished pre-training (not
resumable, and cheap) is started again. So an interrupted reproduction — Ctrl-C, a crash,
``stop_after`` — continues where it stopped when the same command is run again. ``status.json``
records what happened, for the report's wall times and for people reading it.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
from pathlib import Path
from typing import Any

from bimgame import __version__
from bimgame.experiments.budgets import GRID_FIELDS, Budget
from bimgame.experiments.costs import COSTS, CostModel, estimate_seconds
from bimgame.experiments.grid import Piece, plan_pieces
from bimgame.experiments.kinds import kind_of
from bimgame.util.files import read_json, write_json

__all__ = ["PLAN", "STATUS", "timestamp", "write_plan", "load_plan", "load_status", "check_compatible", "piece_done"]

PLAN = "plan.json"
STATUS = "status.json"
_PLAN_FORMAT = "bimgame-reproduction-1"


def timestamp() -> str:
    """Now, in local time with its offset, to the second (the times of ``plan.json``, ``status.json``
    and the report)."""
    return dt.datetime.now().astimezone().isoformat(timespec="seconds")


def write_plan(out_dir: str | Path, budget: Budget, costs: CostModel = COSTS) -> list[Piece]:
    """Write ``plan.json`` (atomically): the budget, every piece with its cost estimate; returns the pieces."""
    out_dir = Path(out_dir)
    pieces = plan_pieces(budget)

    estimates = [estimate_seconds(p, budget, costs) for p in pieces]
    write_json(
        out_dir / PLAN,
        {
            "format": _PLAN_FORMAT,
            "bimgame_version": __version__,
            "written": timestamp(),
            "budget": budget.to_dict(),
            "pieces": [
                {**p.to_dict(), "estimate_seconds": round(e, 1)} for p, e in zip(pieces, estimates, strict=True)
            ],
            "estimate_seconds": round(sum(estimates), 1),
        },
    )
    return pieces


def load_plan(out_dir: str | Path) -> tuple[Budget, list[Piece]]:
    """The budget and pieces of a reproduction directory (its ``plan.json``)."""
    path = Path(out_dir) / PLAN
    stored = read_json(path)
    if stored is None:
        raise ValueError(
            f"{out_dir} is not a reproduction directory (no readable {PLAN}); "
            f"start one with: bimgame reproduce --out {out_dir}"
        )
    if stored.get("format") != _PLAN_FORMAT:
        raise ValueError(
            f"{path} is not a bimgame reproduction plan (format {stored.get('format')!r}, expected {_PLAN_FORMAT!r})"
        )
    try:
        budget = Budget.from_dict(stored["budget"])
        fields = {f.name for f in dataclasses.fields(Piece)}
        pieces = [
            Piece(**{**{k: v for k, v in p.items() if k in fields}, "needs": tuple(p["needs"])})
            for p in stored["pieces"]
        ]
    except (KeyError, TypeError, AttributeError) as error:
        raise ValueError(
            f"{path} is damaged ({type(error).__name__}: {error}); move it away and rerun "
            f"'bimgame reproduce --out {out_dir}' to plan the reproduction anew"
        ) from None
    return budget, pieces


def load_status(out_dir: str | Path) -> dict[str, Any]:
    """``status.json`` of a reproduction directory (an empty status when there is none)."""
    stored = read_json(Path(out_dir) / STATUS)
    return stored if stored is not None else {"pieces": {}, "invocations": []}


def check_compatible(out_dir: str | Path, budget: Budget) -> None:
    """Refuse (ValueError naming the differences) to continue a reproduction directory with settings
    that change what its pieces compute; only :data:`~bimgame.experiments.budgets.GRID_FIELDS` may differ."""
    out_dir = Path(out_dir)
    if not (out_dir / PLAN).exists():
        return
    stored, _ = load_plan(out_dir)
    old, new = stored.compared_settings(), budget.compared_settings()
    changed = [k for k in new if k not in GRID_FIELDS and k != "name" and old.get(k) != new[k]]
    if changed:
        details = "; ".join(f"{k}: {old.get(k)!r} there, {new[k]!r} now" for k in changed)
        raise ValueError(
            f"{out_dir} holds a reproduction with other settings ({details}). Continue it with its "
            f"own budget ('{stored.name}', or no --budget), change only {', '.join(GRID_FIELDS)}, "
            f"or use another --out"
        )


def piece_done(piece: Piece, out_dir: str | Path, budget: Budget) -> bool:
    """Whether ``piece``'s outputs in ``out_dir`` show it finished (its kind decides, see
    :mod:`bimgame.experiments.kinds`)."""
    return kind_of(piece).done(piece, Path(out_dir), budget)
