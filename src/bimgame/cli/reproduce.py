"""``bimgame reproduce`` and ``bimgame report``: the paper's experiments in one command (and, with
``--budget beyond`` or ``ablation``, fine-tuning beyond them), and the figures, tables and report
rebuilt from the saved results."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from bimgame.cli.argtypes import add_backend_arguments, non_negative_int, positive_int
from bimgame.cli.flags import add_settings_flags
from bimgame.experiments.budgets import BUDGETS, Budget, budget_named
from bimgame.experiments.costs import estimate_seconds, format_duration
from bimgame.experiments.grid import plan_pieces
from bimgame.experiments.plan import PLAN, check_compatible, load_plan, piece_done
from bimgame.experiments.report import build_report
from bimgame.experiments.reproduce import reproduce
from bimgame.experiments.statistics import DEFAULT_RESAMPLES

#: Budget settings the command line may change (the grid); ``--budget`` picks the rest.
GRID_FLAGS = ("tasks", "algorithms", "seeds", "obs", "torch_threads")

__all__ = ["add_reproduce_arguments", "add_report_arguments", "run_reproduce", "run_report", "budget_from"]


def _fraction(text: str) -> float:
    """A number in (0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}")
    return value


def add_reproduce_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add(
        "--out",
        type=Path,
        required=True,
        help="directory of the reproduction (created; run the same command again to continue it)",
    )
    add(
        "--budget",
        choices=list(BUDGETS),
        default=None,
        help="preset: quick (STG1, state observations, 2 seeds, < 30 min on 2 cores), paper (FULL/STG1/STG2, "
        "pixels, 5 seeds, about a day), pixels (FULL/STG1/STG2 from pixels, 3 seeds, < 2 h), "
        "beyond (fine-tuning π^s without forgetting it: "
        "STG2/STG3/STG4/FULL, A3C, pre-train + A3C and the keep preset, 3 seeds, < 2 h) or ablation (each "
        "fine-tuning method on STG3, 3 seeds, < 1 h); smoke checks the whole pipeline in a few minutes (numbers "
        "that mean nothing). Default: the budget stored in --out, else quick",
    )
    # The grid: Budget settings that change what is computed; not given: the budget's (as --budget).
    add_settings_flags(
        parser, Budget, GRID_FLAGS, default_none=True, defaults=BUDGETS["quick"], default_text="the budget's"
    )
    add_backend_arguments(parser, "pieces (dataset, pre-trainings, runs)")
    add(
        "--max-retries",
        type=non_negative_int,
        default=3,
        metavar="N",
        help="with --backend ray: how often a piece whose node or worker died is started again (default 3); "
        "A3C, PPO and DAgger runs continue from the last checkpoint they shipped back",
    )
    add(
        "--stop-after",
        type=positive_int,
        default=None,
        metavar="N",
        help="compute at most N pieces, then stop (run again to continue)",
    )
    add("--dry-run", action="store_true", help="print the plan and its expected duration; run nothing")
    add("--no-progress", action="store_true", help="no progress bar (one line per finished piece)")


def add_report_arguments(parser: argparse.ArgumentParser) -> None:
    add = parser.add_argument
    add("out", type=Path, metavar="DIR", help="a reproduction directory (bimgame reproduce --out DIR)")
    add(
        "--threshold",
        type=_fraction,
        default=None,
        metavar="F",
        help="steps-to-threshold target as a fraction of the expert's success rate (default: the budget's, 0.8)",
    )
    add(
        "--resamples",
        type=positive_int,
        default=DEFAULT_RESAMPLES,
        help=f"bootstrap resamples (default {DEFAULT_RESAMPLES})",
    )
    add("--seed", type=int, default=0, help="seed of the bootstrap's generator (default 0)")


def budget_from(args: argparse.Namespace) -> Budget:
    """The budget of a ``reproduce`` command: the preset named by ``--budget`` (else the one stored
    in ``--out``, else ``quick``) with the grid flags applied."""
    if args.budget is not None:
        base = budget_named(args.budget)
    elif (args.out / PLAN).is_file():
        base, _ = load_plan(args.out)
    else:
        base = budget_named("quick")
    return base.with_grid(**{name: getattr(args, name) for name in GRID_FLAGS})


def run_reproduce(args: argparse.Namespace) -> int:
    """``bimgame reproduce``: print the plan's expected duration, run (or continue) it, build the
    report. Exit status 0 when every piece finished, 1 when some failed, 130 when interrupted."""
    console = Console(stderr=True)
    if args.ray_address is not None and args.backend != "ray":
        console.print("bimgame reproduce: error: --ray-address is only used with --backend ray")
        return 2
    budget = budget_from(args)
    check_compatible(args.out, budget)
    pieces = plan_pieces(budget)
    total = _total(budget)
    left = [p for p in pieces if not piece_done(p, args.out, budget)] if args.out.is_dir() else pieces
    presets = "; ".join(
        f"{name}: {len(plan_pieces(b))} pieces, ≈ {format_duration(_total(b))}" for name, b in BUDGETS.items()
    )
    console.print(
        f"budget {budget.name}: tasks {', '.join(budget.tasks)}; {', '.join(budget.algorithms)}; "
        f"{budget.seeds} seeds; {budget.obs} observations"
    )
    console.print(
        f"expected on an idle 2-core machine: ≈ {format_duration(total)} for all {len(pieces)} pieces, "
        f"≈ {format_duration(sum(estimate_seconds(p, budget) for p in left))} for the {len(left)} not "
        f"finished yet (presets — {presets}). A concurrent job on the machine makes it slower."
    )
    if args.dry_run:
        for piece in pieces:
            state = "to do" if piece in left else "done"
            console.print(f"  {piece.id:<40} {state:<6} ≈ {format_duration(estimate_seconds(piece, budget))}")
        kinds = dict.fromkeys(p.kind for p in pieces)
        console.print(
            "by kind: "
            + "; ".join(
                f"{kind} ×{sum(p.kind == kind for p in pieces)} ≈ "
                f"{format_duration(sum(estimate_seconds(p, budget) for p in pieces if p.kind == kind))}"
                for kind in kinds
            )
        )
        return 0
    try:
        result = reproduce(
            args.out,
            budget,
            progress=not args.no_progress,
            stop_after=args.stop_after,
            console=console,
            backend=args.backend,
            ray_address=args.ray_address,
            max_retries=args.max_retries,
        )
    except ImportError as error:
        console.print(f"bimgame reproduce: error: {escape(str(error))}")
        return 2
    except KeyboardInterrupt:
        console.print(f"interrupted; finished pieces are kept. Continue with: bimgame reproduce --out {args.out}")
        return 130
    paths = build_report(args.out)
    console.print(
        f"{len(result.computed)} pieces computed, {len(result.reused)} reused, in "
        f"{format_duration(result.seconds)}; wrote {paths.report}"
    )
    if result.remaining:
        console.print(
            f"stopped after {len(result.computed)} pieces as asked; {len(result.remaining)} left. "
            f"Continue with: bimgame reproduce --out {args.out}"
        )
    if result.failed or result.skipped:
        for failed, message in result.failed.items():
            console.print(f"[red]failed[/red] {escape(failed)}: {escape(message)}")
        if result.skipped:
            console.print(f"not run because a piece they need failed: {', '.join(result.skipped)}")
        console.print(f"details in {args.out / 'status.json'}; rerun the same command to retry")
        return 1
    return 0


def _total(budget: Budget) -> float:
    """Expected seconds of all pieces of a budget."""
    return sum(estimate_seconds(p, budget) for p in plan_pieces(budget))


def run_report(args: argparse.Namespace) -> int:
    """``bimgame report DIR``: rebuild the figures, tables and report.md from DIR's saved results."""
    paths = build_report(args.out, threshold_fraction=args.threshold, resamples=args.resamples, seed=args.seed)
    for path in paths.all():
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit("use: bimgame reproduce|report ...")
