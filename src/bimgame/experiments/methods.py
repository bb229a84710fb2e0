"""The A3C settings that make each algorithm of a reproduction what it is:
:func:`finetune_overrides`, one line per algorithm of :data:`_METHODS`, and what follows from them
(:func:`needs_expert_data`, :func:`uses_start_curriculum`).

The paper's A3C algorithms differ only in their initial weights and reward (see
:mod:`bimgame.experiments.runners`); the methods beyond it differ in their fine-tuning settings
(:mod:`bimgame.learn.finetune`). Every method is the ``paper`` preset (plain fine-tuning, every
method off) with the one method it tests turned on, taking its values from the ``keep`` preset —
so an ablation measures exactly the method the ``keep`` combination uses. The values are read
from :data:`~bimgame.learn.finetune.FINETUNE_PRESETS` each time, never copied: a change of a preset
changes the runs planned after it. Adding a method is one line of :data:`_METHODS` (and its name in
:data:`~bimgame.experiments.budgets.ALGORITHMS`).

``pretrain+a3c`` records the ``paper`` preset (``finetune="paper"``), whose settings are A3C's
defaults: its runs compute what they did before the presets existed.
"""

from __future__ import annotations

from typing import Any, Callable

from bimgame.experiments.budgets import ALGORITHMS, uses_policy
from bimgame.learn.finetune import FINETUNE_PRESETS

__all__ = ["BC_COEF", "KEEPFADE_FRACTION", "A3C_ALGORITHMS", "finetune_overrides", "needs_expert_data",
           "uses_start_curriculum"]

#: ``pretrain+a3c+bc``: initial weight of the behaviour-cloning term (it decays to zero over the run).
BC_COEF = 0.1
#: ``pretrain+a3c+keepfade``: the ``keep`` preset with its KL weight fading to zero over the first
#: 1/KEEPFADE_FRACTION of the run. From pixels on STG1 (600k steps, 3 seeds), a KL fading over 200k
#: steps reached 80% training success 1.46× sooner than A3C, where the constant KL of ``keep`` held
#: the policy near a π^s that solves STG1 from pixels only 20–35% of the time and never got there
#: (``docs/pixels/keep_decay_stg1.json``). From state on STG3 a fading KL let π^s be forgotten once
#: it reached zero, which is why ``keep`` itself keeps it constant.
KEEPFADE_FRACTION = 3


def _preset(name: str, **changes: Any) -> dict[str, Any]:
    """The settings of fine-tuning preset ``name`` (its name recorded), with ``changes``."""
    return {**FINETUNE_PRESETS[name], "finetune": name, **changes}


def _paper_with_keep(*fields: str) -> dict[str, Any]:
    """Plain fine-tuning with the ``keep`` preset's values of ``fields`` (one method turned on)."""
    return _preset("paper", **{field: FINETUNE_PRESETS["keep"][field] for field in fields})


#: Per A3C algorithm: its settings as a function of the run's steps (DAgger is not an A3C run).
_METHODS: dict[str, Callable[[int], dict[str, Any]]] = {
    "a3c": lambda steps: {},
    "pretrain+a3c": lambda steps: _preset("paper"),
    "a3c+value": lambda steps: {},
    "pretrain+a3c+value": lambda steps: {},
    "pretrain+a3c+warmup": lambda steps: _paper_with_keep("critic_warmup_steps", "actor_ramp_steps"),
    "pretrain+a3c+kl": lambda steps: _paper_with_keep("kl_coef", "kl_decay_steps", "kl_temperature"),
    "pretrain+a3c+norm": lambda steps: _preset("paper", advantage_norm=True),
    "pretrain+a3c+bc": lambda steps: _preset("paper", bc_coef=BC_COEF, bc_decay_steps=steps),
    "pretrain+a3c+demo": lambda steps: _preset("paper", start_curriculum="demo"),
    "pretrain+a3c+keep": lambda steps: _preset("keep"),
    "pretrain+a3c+keepfade": lambda steps: _preset("keep", kl_decay_steps=max(1, steps // KEEPFADE_FRACTION)),
    "a3c+reverse": lambda steps: {"start_curriculum": "reverse"},
    # The paper's network whatever the budget's levers: no privileged heads or critic, no augmentation.
    "a3c+papernet": lambda steps: {"aux_heads": False, "asymmetric_critic": False, "augment_shift": 0},
}
#: The algorithms whose runs are A3C runs (every one but DAgger), in :data:`ALGORITHMS`' order.
A3C_ALGORITHMS = tuple(a for a in ALGORITHMS if a in _METHODS)


def _reads_expert_data(settings: dict[str, Any]) -> bool:
    """Whether A3C settings read an expert dataset (a behaviour-cloning term or demonstration starts)."""
    return settings.get("bc_coef", 0.0) > 0 or settings.get("start_curriculum", "none") == "demo"


def finetune_overrides(algorithm: str, steps: int, data_dir: str | None) -> dict[str, Any]:
    """The A3C settings (field → value) that ``algorithm``'s run sets beyond the budget's, for a run
    of ``steps`` environment steps; ``data_dir`` is the reproduction's expert dataset, given as
    ``expert_data`` to the algorithms that read it (a ValueError when they need it and it is None)."""
    if algorithm not in _METHODS:
        raise ValueError(f"unknown A3C algorithm {algorithm!r}; allowed: {', '.join(A3C_ALGORITHMS)}"
                         + (" (DAgger is not an A3C run)" if algorithm == "dagger" else ""))
    if not (isinstance(steps, int) and steps >= 1):
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
    settings = _METHODS[algorithm](steps)
    if settings.get("kl_coef", 0.0) > 0 and not uses_policy(algorithm):
        raise ValueError(f"{algorithm}: kl_coef > 0 needs the run to start from π^s; allowed only for pretrain+… "
                         f"algorithms")
    if _reads_expert_data(settings):
        if data_dir is None:
            raise ValueError(f"{algorithm} reads the expert dataset (bc_coef > 0 or start_curriculum='demo'): "
                             f"give data_dir, the reproduction's DIR/data")
        settings["expert_data"] = str(data_dir)
    return settings


def needs_expert_data(algorithm: str) -> bool:
    """Whether ``algorithm``'s runs read the expert dataset (so they need the ``data`` piece); DAgger's
    own data come from the expert it queries, not from the dataset."""
    return algorithm in _METHODS and _reads_expert_data(finetune_overrides(algorithm, 1, "data"))


def uses_start_curriculum(algorithm: str) -> bool:
    """Whether ``algorithm``'s training episodes start elsewhere than the task's own starts (a start
    curriculum): their training success is then not the task's, only their evaluations are."""
    return algorithm in _METHODS and _METHODS[algorithm](1).get("start_curriculum", "none") != "none"
