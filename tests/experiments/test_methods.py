"""Each algorithm's A3C settings (methods.finetune_overrides), derived from the fine-tuning presets at
run time, and what follows from them: which pieces a run needs and how an unfinished run resumes."""

from __future__ import annotations

import dataclasses

import pytest

from bimgame.experiments.budgets import ALGORITHMS, PAPER_ALGORITHMS, Budget, uses_policy, uses_value
from bimgame.experiments.grid import plan_pieces
from bimgame.experiments.methods import (
    A3C_ALGORITHMS,
    BC_COEF,
    finetune_overrides,
    needs_expert_data,
    ppo_overrides,
    uses_start_curriculum,
)
from bimgame.experiments.runners import _with_stored_preset_name, a3c_config_for
from bimgame.learn.a3c import A3CConfig
from bimgame.learn.learner_settings import FINETUNE_FIELDS, FINETUNE_PRESETS

STEPS = 500_000
DATA = "/repro/data"


def _changed_from_paper(algorithm: str) -> dict:
    """The settings an algorithm sets beyond plain fine-tuning (its preset name left out)."""
    settings = finetune_overrides(algorithm, STEPS, DATA)
    return {k: v for k, v in settings.items() if k != "finetune" and FINETUNE_PRESETS["paper"].get(k) != v}


def test_every_algorithm_but_dagger_is_an_a3c_run_and_the_paper_ones_come_first():
    assert ALGORITHMS[:5] == PAPER_ALGORITHMS
    assert set(A3C_ALGORITHMS) == set(ALGORITHMS) - {"dagger", "ppo", "pretrain+ppo", "pretrain+ppo+keep"}
    # The paper's A3C algorithms keep A3C's defaults; pre-train + A3C records the paper preset (all off).
    for algorithm in ("a3c", "a3c+value", "pretrain+a3c+value"):
        assert finetune_overrides(algorithm, STEPS, DATA) == {}
    assert finetune_overrides("pretrain+a3c", STEPS, DATA) == {**FINETUNE_PRESETS["paper"], "finetune": "paper"}
    default = A3CConfig().to_dict()
    assert all(default[field] == value for field, value in FINETUNE_PRESETS["paper"].items())


def test_each_method_turns_on_the_keep_presets_values_of_its_own_settings_only():
    keep = FINETUNE_PRESETS["keep"]
    assert _changed_from_paper("pretrain+a3c+warmup") == {"critic_warmup_steps": keep["critic_warmup_steps"],
                                                           "actor_ramp_steps": keep["actor_ramp_steps"]}
    kl = finetune_overrides("pretrain+a3c+kl", STEPS, DATA)
    assert (kl["kl_coef"], kl["kl_decay_steps"], kl["kl_temperature"]) == \
        (keep["kl_coef"], keep["kl_decay_steps"], keep["kl_temperature"])
    assert set(_changed_from_paper("pretrain+a3c+kl")) <= {"kl_coef", "kl_decay_steps", "kl_temperature"}
    assert _changed_from_paper("pretrain+a3c+norm") == {"advantage_norm": True}
    assert _changed_from_paper("pretrain+a3c+bc") == {"bc_coef": BC_COEF, "bc_decay_steps": STEPS, "expert_data": DATA}
    assert _changed_from_paper("pretrain+a3c+demo") == {"start_curriculum": "demo", "expert_data": DATA}
    for algorithm in ("pretrain+a3c+warmup", "pretrain+a3c+kl", "pretrain+a3c+norm", "pretrain+a3c+bc",
                      "pretrain+a3c+demo"):
        assert finetune_overrides(algorithm, STEPS, DATA)["finetune"] == "paper", algorithm
    settings = finetune_overrides("pretrain+a3c+keep", STEPS, DATA)
    assert settings == {**keep, "finetune": "keep"}  # the shipped keep preset reads no expert data
    # keepfade: keep, with its KL fading to zero over the first third of the run (200k of a 600k run).
    assert finetune_overrides("pretrain+a3c+keepfade", 600_000, DATA) == {**keep, "finetune": "keep",
                                                                         "kl_decay_steps": 200_000}
    assert finetune_overrides("pretrain+a3c+keepfade", 2, DATA)["kl_decay_steps"] == 1
    assert finetune_overrides("a3c+reverse", STEPS, DATA) == {"start_curriculum": "reverse"}


def test_the_settings_follow_the_presets_at_run_time(monkeypatch):
    monkeypatch.setitem(FINETUNE_PRESETS, "keep", {**FINETUNE_PRESETS["keep"], "kl_coef": 0.25, "bc_coef": 0.05,
                                                   "bc_decay_steps": 123})
    assert finetune_overrides("pretrain+a3c+kl", STEPS, DATA)["kl_coef"] == 0.25
    keep = finetune_overrides("pretrain+a3c+keep", STEPS, DATA)
    assert keep["bc_coef"] == 0.05 and keep["expert_data"] == DATA  # a keep preset with BC reads the dataset
    assert needs_expert_data("pretrain+a3c+keep")
    piece = next(p for p in plan_pieces(Budget(tasks=("STG3",), algorithms=("pretrain+a3c+keep",), seeds=1))
                 if p.kind == "a3c")
    assert piece.needs == ("data", "pretrain/STG3/policy-seed0")


def test_which_runs_need_the_dataset_pi_s_or_v_hat():
    assert [a for a in ALGORITHMS if needs_expert_data(a)] == ["pretrain+a3c+bc", "pretrain+a3c+demo"]
    assert [a for a in ALGORITHMS if uses_start_curriculum(a)] == ["pretrain+a3c+demo", "a3c+reverse"]
    assert [a for a in ALGORITHMS if uses_value(a)] == ["a3c+value", "pretrain+a3c+value"]
    assert not uses_policy("a3c+reverse") and all(uses_policy(a) for a in ALGORITHMS if a.startswith("pretrain"))
    budget = Budget(tasks=("STG3",), algorithms=A3C_ALGORITHMS, seeds=1)
    needs = {p.algorithm: p.needs for p in plan_pieces(budget) if p.kind == "a3c"}
    policy, value = "pretrain/STG3/policy-seed0", "pretrain/STG3/value-seed0"
    assert needs == {"a3c": (), "pretrain+a3c": (policy,), "a3c+value": (value,),
                     "pretrain+a3c+value": (policy, value), "pretrain+a3c+warmup": (policy,),
                     "pretrain+a3c+kl": (policy,), "pretrain+a3c+norm": (policy,),
                     "pretrain+a3c+bc": ("data", policy), "pretrain+a3c+demo": ("data", policy),
                     "pretrain+a3c+keep": (policy,), "pretrain+a3c+keepfade": (policy,), "a3c+reverse": (),
                     "a3c+papernet": ()}
    # Without π^s in the grid no policy is pre-trained.
    ids = [p.id for p in plan_pieces(Budget(tasks=("STG3",), algorithms=("a3c+reverse",), seeds=1))]
    assert ids == ["data", "runs/STG3/a3c-reverse/seed0"]


def test_a3c_settings_of_every_algorithm_are_valid_and_record_the_dataset(tiny_budget):
    budget = dataclasses.replace(tiny_budget, algorithms=A3C_ALGORITHMS)
    for algorithm in A3C_ALGORITHMS:
        config = a3c_config_for(budget, "STG1", 1, algorithm, DATA)
        assert config.schedule.steps == 2_000 and config.seed == 1, algorithm
        assert config.expert_data == (DATA if needs_expert_data(algorithm) else None), algorithm
        kl_coef = 0 if config.finetuning is None else config.finetuning.kl_coef
        assert kl_coef == 0 or uses_policy(algorithm), algorithm  # kickstarting needs π^s to start from
    bc = a3c_config_for(budget, "STG1", 0, "pretrain+a3c+bc", DATA)
    assert bc.finetuning is not None and bc.finetuning.bc_decay_steps == 2_000  # decays over the run
    assert a3c_config_for(budget, "STG1", 0) == a3c_config_for(budget, "STG1", 0, "a3c")


def test_pixel_levers_reach_every_network_but_the_papers_and_daggers(tiny_budget):
    """With the budget's levers on, every A3C run and π^s use them; ``a3c+papernet`` is the paper's
    exact network; DAgger's learner has no privileged parts (its rollouts record no states)."""
    from bimgame.experiments.runners import dagger_config_for, pretrain_config_for
    network = {"aux_heads": True, "asymmetric_critic": True, "precision": "bf16"}
    budget = tiny_budget.replace(obs="pixels", network=network, a3c={"augment_shift": 2}, algorithms=A3C_ALGORITHMS)
    for algorithm in A3C_ALGORITHMS:
        config = a3c_config_for(budget, "STG1", 0, algorithm, DATA)
        levers = (config.network.aux_heads, config.network.asymmetric_critic, config.optimization.augment_shift)
        assert levers == ((False, False, 0) if algorithm == "a3c+papernet" else (True, True, 2)), algorithm
        assert config.network.precision == "bf16"
    policy = pretrain_config_for(budget, "STG1", 0, "policy")
    assert (policy.aux_heads, policy.asymmetric_critic, policy.precision) == (True, True, "bf16")
    learner = dagger_config_for(budget, "STG1", 0).learner
    assert (learner.aux_heads, learner.asymmetric_critic, learner.precision) == (False, False, "bf16")
    with pytest.raises(ValueError, match="augment_shift"):
        tiny_budget.replace(obs="state", a3c={"augment_shift": 2})
    with pytest.raises(ValueError, match="precision"):
        tiny_budget.replace(network={"precision": "half"})


@pytest.mark.parametrize("call, message", [
    (lambda: finetune_overrides("sac", STEPS, DATA),
     r"unknown A3C algorithm 'sac'; allowed: a3c, pretrain\+a3c, a3c\+value, .*pretrain\+a3c\+keep, "
     r"pretrain\+a3c\+keepfade, a3c\+reverse, a3c\+papernet$"),
    (lambda: finetune_overrides("ppo", STEPS, DATA), r"unknown A3C algorithm 'ppo'.*\(PPO is not an A3C run\)$"),
    (lambda: ppo_overrides("a3c", STEPS, DATA),
     r"unknown PPO algorithm 'a3c'; allowed: ppo, pretrain\+ppo, pretrain\+ppo\+keep \(A3C is not a PPO run\)$"),
    (lambda: finetune_overrides("dagger", STEPS, DATA), r"unknown A3C algorithm 'dagger'.*not an A3C run"),
    (lambda: finetune_overrides("pretrain+a3c+bc", 0, DATA), r"steps must be an integer >= 1, got 0"),
    (lambda: finetune_overrides("pretrain+a3c+demo", STEPS, None),
     r"pretrain\+a3c\+demo reads the expert dataset .*give data_dir"),
])
def test_bad_requests_are_refused_naming_what_is_allowed(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_an_unfinished_run_resumes_with_the_preset_name_it_was_started_with(tiny_budget):
    """A pre-train + A3C run started before it recorded finetune="paper" (None then) has the same
    settings: it resumes as it was started instead of failing the resume's settings check."""
    config = a3c_config_for(tiny_budget, "STG1", 0, "pretrain+a3c", DATA)
    assert config.finetuning is not None and config.finetuning.finetune == "paper"
    stored = {f: v for f, v in config.to_dict().items() if f not in FINETUNE_FIELDS and f != "finetune"}
    assert _with_stored_preset_name(stored, config).to_dict()["finetune"] is None
    # Other settings than the name: left as they are (the resume then names the difference).
    assert _with_stored_preset_name({**stored, "kl_coef": 1.0}, config) == config
    keep = a3c_config_for(tiny_budget, "STG1", 0, "pretrain+a3c+keep", DATA)
    assert _with_stored_preset_name(keep.to_dict(), keep) == keep


def test_a_ppo_run_gets_the_a3c_runs_steps_evaluations_and_network_with_ppos_own_settings():
    from bimgame.experiments.runners import ppo_config_for

    budget = Budget(tasks=("STG2",), algorithms=("a3c", "ppo", "pretrain+ppo"), obs="pixels", seeds=1).replace(
        a3c={"steps": {"STG2": 123_456}, "eval_every": 10_000, "eval_episodes": 7, "checkpoint_every": 5_000},
        network={"aux_heads": True, "hidden": 32}, ppo={"n_steps": 64, "lr": 1e-4})
    assert ppo_overrides("ppo", STEPS, DATA) == {} and ppo_overrides("pretrain+ppo", STEPS, DATA) == {}
    for algorithm in ("ppo", "pretrain+ppo"):
        config = ppo_config_for(budget, "STG2", 3, algorithm)
        schedule, optimization = config.schedule, config.optimization
        assert (config.task, config.seed) == ("STG2", 3)
        assert (schedule.steps, schedule.eval_every, schedule.eval_episodes, schedule.checkpoint_every) == (
            budget.steps_for("STG2"), 10_000, 7, 5_000)
        assert (schedule.workers, schedule.envs_per_worker) == (1, 16)
        assert (optimization.n_steps, optimization.lr, optimization.epochs) == (64, 1e-4, 4)
        a3c = a3c_config_for(budget, "STG2", 3)
        assert config.network == a3c.network  # the networks π^s is pre-trained with
