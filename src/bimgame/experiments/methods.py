"""The settings that make each algorithm of a reproduction what it is, read from its record in
:mod:`bimgame.experiments.algorithms`: :func:`finetune_overrides` for A3C's runs and
:func:`ppo_overrides` for PPO's (with the expert's dataset for the algorithms that read it), and
what follows from them (:func:`needs_expert_data`, :func:`uses_start_curriculum`).

Adding an algorithm is one :func:`~bimgame.experiments.algorithms.register` call with its
:class:`~bimgame.experiments.algorithms.Algorithm` record (name, label, what its runs need, its
settings); nothing here changes.
"""

from __future__ import annotations

from typing import Any

from bimgame.experiments.algorithms import (
    BC_COEF,
    KEEPFADE_FRACTION,
    Algorithm,
    Learner,
    algorithm_named,
    algorithm_names,
    reads_expert_data,
    registered,
)

__all__ = [
    "BC_COEF",
    "KEEPFADE_FRACTION",
    "A3C_ALGORITHMS",
    "a3c_algorithms",
    "finetune_overrides",
    "ppo_overrides",
    "needs_expert_data",
    "uses_start_curriculum",
]


def a3c_algorithms() -> tuple[str, ...]:
    """The registered algorithms whose runs are A3C runs, in the registry's order."""
    return tuple(a.name for a in registered() if a.learner is Learner.A3C)


#: The built-in algorithms whose runs are A3C runs (every one but DAgger), in the registry's order.
A3C_ALGORITHMS = a3c_algorithms()


def _learner_record(algorithm: str, learner: Learner) -> Algorithm:
    """The record of ``algorithm``, run by ``learner``; a ValueError listing that learner's algorithms otherwise."""
    records = {a.name: a for a in registered() if a.learner is learner}
    name = learner.name
    if algorithm not in records:
        other = algorithm_named(algorithm) if algorithm in algorithm_names() else None
        raise ValueError(
            f"unknown {name} algorithm {algorithm!r}; allowed: {', '.join(records)}"
            + (f" ({other.label} is not {'an' if name[0] in 'AEIOU' else 'a'} {name} run)" if other else "")
        )
    return records[algorithm]


def finetune_overrides(algorithm: str, steps: int, data_dir: str | None) -> dict[str, Any]:
    """The A3C settings (field → value) that ``algorithm``'s run sets beyond the budget's, for a run
    of ``steps`` environment steps; ``data_dir`` is the reproduction's expert dataset, given as
    ``expert_data`` to the algorithms that read it (a ValueError when they need it and it is None)."""
    return _overrides(_learner_record(algorithm, Learner.A3C), steps, data_dir)


def ppo_overrides(algorithm: str, steps: int, data_dir: str | None) -> dict[str, Any]:
    """The PPO settings (flat name → value) that ``algorithm``'s run sets beyond the budget's ``ppo``
    group, for a run of ``steps`` environment steps (``data_dir`` as for :func:`finetune_overrides`)."""
    return _overrides(_learner_record(algorithm, Learner.PPO), steps, data_dir)


def _overrides(record: Algorithm, steps: int, data_dir: str | None) -> dict[str, Any]:
    """The settings ``record``'s runs of ``steps`` steps set, checked: a KL to π^s only from π^s, and
    the dataset's place for the settings that read it."""
    algorithm = record.name
    if not (isinstance(steps, int) and steps >= 1):
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
    settings = record.run_settings(steps)
    if settings.get("kl_coef", 0.0) > 0 and not record.starts_from_policy:
        raise ValueError(
            f"{algorithm}: kl_coef > 0 needs the run to start from π^s; allowed only for algorithms "
            f"that start from it (starts_from_policy)"
        )
    if reads_expert_data(settings):
        if data_dir is None:
            raise ValueError(
                f"{algorithm} reads the expert dataset (bc_coef > 0 or demonstration starts): "
                f"give data_dir, the reproduction's DIR/data"
            )
        settings["expert_data"] = str(data_dir)
    return settings


def needs_expert_data(algorithm: str) -> bool:
    """Whether ``algorithm``'s runs read the expert dataset (so they need the ``data`` piece); DAgger's
    own data come from the expert it queries, not from the dataset."""
    return algorithm in algorithm_names() and algorithm_named(algorithm).needs_expert_data


def uses_start_curriculum(algorithm: str) -> bool:
    """Whether ``algorithm``'s training episodes start elsewhere than the task's own starts (a start
    curriculum): their training success is then not the task's, only their evaluations are."""
    return algorithm in algorithm_names() and algorithm_named(algorithm).start_curriculum
