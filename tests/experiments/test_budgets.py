"""Budgets and their validation, the pieces they plan and the cost estimates of the presets."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from bimgame.experiments.budgets import (
    ALGORITHMS,
    BUDGETS,
    FLAT_FIELDS,
    PAPER_ALGORITHMS,
    PAPER_TASKS,
    Budget,
    NetworkBudget,
    budget_named,
)
from bimgame.experiments.algorithms import algorithm_named
from bimgame.experiments.costs import cluster_seconds, estimate_seconds, piece_cpus
from bimgame.experiments.grid import plan_pieces
from bimgame.experiments.kinds import kind_of
from bimgame.experiments.methods import needs_expert_data
from bimgame.experiments.plan import check_compatible, write_plan


@pytest.mark.parametrize("changes, message", [
    ({"tasks": ("STG9",)}, r"Budget.tasks: unknown task 'STG9'; allowed: FULL, STG1, STG2, STG3, STG4"),
    ({"tasks": ()}, r"Budget.tasks must name at least one task"),
    ({"algorithms": ("sac",)}, r"Budget.algorithms: unknown \['sac'\]; allowed: a3c, pretrain\+a3c, a3c\+value, "
                               r"pretrain\+a3c\+value, dagger, pretrain\+a3c\+warmup, pretrain\+a3c\+kl, "
                               r"pretrain\+a3c\+norm, pretrain\+a3c\+bc, pretrain\+a3c\+demo, pretrain\+a3c\+keep, "
                               r"pretrain\+a3c\+keepfade, a3c\+reverse, a3c\+papernet, ppo, pretrain\+ppo, pretrain\+ppo\+keep$"),
    ({"seeds": 0}, r"Budget.seeds must be an integer >= 1, got 0"),
    ({"obs": "rgb"}, r"Budget.obs must be one of pixels, state, got 'rgb'"),
    ({"threshold_fraction": 0.0}, r"Budget.threshold_fraction must be in \(0, 1\], got 0.0"),
    ({"tasks": ("STG2",), "a3c": {"steps": {"STG1": 10}}}, r"Budget.a3c.steps has no entry for \['STG2'\]"),
    ({"a3c": {"steps": {"STG1": 0}}}, r"Budget.a3c.steps\['STG1'\] must be an integer >= 1, got 0"),
    ({"a3c": {"steps": {"STG9": 10}}}, r"Budget.a3c.steps: unknown task 'STG9'; allowed: FULL, STG1"),
    ({"tasks": ("STG2",), "dataset": {"task": "STG1"}, "a3c": {"steps": {"STG2": 10}}},
     r"Budget.dataset.task STG1 cannot label \['STG2'\].*dataset.task='FULL'"),
    ({"dataset": {"episodes": 0}}, r"Budget.dataset.episodes must be an integer >= 1, got 0$"),
    ({"dataset": {"max_steps": 0}}, r"Budget.dataset.max_steps must be an integer >= 1, got 0$"),
    ({"network": {"hidden": 0}}, r"Budget.network.hidden must be an integer >= 1, got 0$"),
    ({"network": {"aux_heads": 1}}, r"Budget.network.aux_heads must be True or False, got 1$"),
    ({"a3c": {"eval_every": -1}}, r"Budget.a3c.eval_every must be an integer >= 0, got -1$"),
    ({"a3c": {"augment_shift": 9}}, r"Budget.a3c.augment_shift must be 0..2 pixels, and 0 for state observations"),
    ({"pretrain": {"patience": 0}}, r"Budget.pretrain.patience must be an integer >= 1, got 0$"),
    ({"value": {"batch_frames": 0}}, r"Budget.value.batch_frames must be an integer >= 1, got 0$"),
    ({"dagger": {"eval_episodes": -1}}, r"Budget.dagger.eval_episodes must be an integer >= 0, got -1$"),
    ({"dagger": {"epochs": 0}}, r"Budget.dagger.epochs must be an integer >= 1, got 0$"),
    ({"torch_threads": 0}, r"Budget.torch_threads must be an integer >= 1, got 0$"),
])
def test_bad_budgets_are_rejected_naming_the_field_and_what_is_allowed(changes, message, tiny_budget):
    with pytest.raises(ValueError, match=message):
        tiny_budget.replace(**changes)
    with pytest.raises(ValueError, match="unknown budget 'huge'; allowed: quick, paper, pixels, beyond, ablation, smoke$"):
        budget_named("huge")


def test_plan_of_the_presets_and_their_estimates():
    quick, paper = BUDGETS["quick"], BUDGETS["paper"]
    pieces = plan_pieces(quick)
    assert [p.id for p in pieces[:8]] == [
        "data", "pretrain/STG1/policy-seed0", "pretrain/STG1/value-seed0", "runs/STG1/a3c/seed0",
        "runs/STG1/pretrain-a3c/seed0", "runs/STG1/a3c-value/seed0", "runs/STG1/pretrain-a3c-value/seed0",
        "runs/STG1/dagger/seed0"]
    assert quick.algorithms == paper.algorithms == PAPER_ALGORITHMS  # the paper's presets: the paper's methods
    assert len(pieces) == 1 + 2 * 2 + 2 * len(PAPER_ALGORITHMS) and len({p.id for p in pieces}) == len(pieces)
    by_id = {p.id: p for p in pieces}
    assert by_id["runs/STG1/pretrain-a3c-value/seed1"].needs == ("pretrain/STG1/policy-seed1",
                                                                  "pretrain/STG1/value-seed1")
    assert by_id["runs/STG1/a3c/seed1"].needs == () and by_id["runs/STG1/dagger/seed1"].needs == ()
    # Pieces run only after what they need.
    order = [p.id for p in pieces]
    assert all(order.index(n) < order.index(p.id) for p in pieces for n in p.needs)
    quick_seconds = sum(estimate_seconds(p, quick) for p in pieces)
    paper_seconds = sum(estimate_seconds(p, paper) for p in plan_pieces(paper))
    assert 5 * 60 < quick_seconds < 30 * 60  # the quick budget's promise, on an idle two-core machine
    assert paper_seconds > 24 * 3600
    # Only the pieces the algorithms need are planned.
    ids = [p.id for p in plan_pieces(quick.with_grid(algorithms=["dagger", "a3c"], seeds=1))]
    assert ids == ["data", "runs/STG1/a3c/seed0", "runs/STG1/dagger/seed0"]


def test_the_presets_beyond_the_paper_plan_their_grids_within_two_hours(tmp_path):
    beyond, ablation = BUDGETS["beyond"], BUDGETS["ablation"]
    assert beyond.tasks == ("STG2", "STG3", "STG4", "FULL") and beyond.seeds == ablation.seeds == 3
    assert beyond.algorithms == ("a3c", "pretrain+a3c", "pretrain+a3c+keep")
    # The ablation: each fine-tuning method on its own, and keep (not keepfade, a variant of keep for weak π^s).
    assert ablation.tasks == ("STG3",)
    finetuning = {a for a in ALGORITHMS if algorithm_named(a).finetuning}
    # (A3C's methods: PPO's keep is a learner's comparison, not one of the ablation's methods)
    assert set(ablation.algorithms) == finetuning - {"pretrain+a3c+keepfade", "pretrain+ppo+keep"} | {"pretrain+a3c"}
    assert [beyond.steps_for(t) for t in beyond.tasks] == [400_000, 500_000, 500_000, 500_000]
    for budget in (beyond, ablation):
        assert (budget.obs, budget.a3c.eval_every, budget.a3c.eval_episodes) == ("state", 50_000, 20)
        assert (budget.dataset.task, budget.dataset.episodes, budget.pretrain.eval_episodes) == ("FULL", 80, 50)
    pieces = plan_pieces(beyond)
    # The dataset, then per task and seed π^s and the three runs.
    assert len(pieces) == 1 + 4 * 3 * (1 + 3)
    assert [p.id for p in pieces[:5]] == ["data", "pretrain/STG2/policy-seed0", "runs/STG2/a3c/seed0",
                                          "runs/STG2/pretrain-a3c/seed0", "runs/STG2/pretrain-a3c-keep/seed0"]
    keep = next(p for p in pieces if p.id == "runs/FULL/pretrain-a3c-keep/seed2")
    assert keep.needs == (("data",) if needs_expert_data("pretrain+a3c+keep") else ()) + ("pretrain/FULL/policy-seed2",)
    pieces = plan_pieces(ablation)
    assert len(pieces) == 1 + 3 * (1 + 8) and not any(p.kind == "pretrain-value" for p in pieces)
    by_id = {p.id: p for p in pieces}
    assert by_id["runs/STG3/pretrain-a3c-bc/seed1"].needs == ("data", "pretrain/STG3/policy-seed1")
    assert by_id["runs/STG3/a3c-reverse/seed1"].needs == ()
    for budget in (beyond, ablation):
        assert sum(estimate_seconds(p, budget) for p in plan_pieces(budget)) < 2 * 3600, budget.name
    # Only the grid differs: either preset continues the other's directory.
    write_plan(tmp_path, beyond)
    check_compatible(tmp_path, ablation)


def test_the_pixel_preset_is_the_papers_grid_from_pixels_within_two_hours():
    pixels = BUDGETS["pixels"]
    assert pixels.tasks == PAPER_TASKS and pixels.obs == "pixels" and pixels.seeds >= 3
    assert set(PAPER_ALGORITHMS) | {"a3c+papernet"} == set(pixels.algorithms)
    network = pixels.network
    assert (network.aux_heads, network.asymmetric_critic, network.precision) == (True, True, "bf16")
    assert not pixels.network.subtract_background  # the paper's network row is the paper's exact configuration
    seconds = sum(estimate_seconds(p, pixels) for p in plan_pieces(pixels))
    assert seconds <= 2 * 3600, seconds / 3600
    # The bf16 rates are the ones that count: the same grid in float32 is expected to take longer.
    fp32 = sum(estimate_seconds(p, pixels.replace(network={"precision": "fp32"})) for p in plan_pieces(pixels))
    assert fp32 > 1.1 * seconds


def test_cpus_per_piece_and_the_expected_duration_on_a_cluster(tiny_budget):
    budget = tiny_budget.replace(a3c={"workers": 2, "eval_every": 1_000}, dataset={"workers": 3}, torch_threads=1)
    pieces = plan_pieces(budget)
    cpus = {p.kind: piece_cpus(p, budget) for p in pieces}
    assert cpus == {"dataset": 3, "pretrain-policy": 1, "pretrain-value": 1, "a3c": 3, "dagger": 1}
    estimates = {p.id: estimate_seconds(p, budget) for p in pieces}
    reserved = sum(estimates[p.id] * piece_cpus(p, budget) for p in pieces)
    # Few CPUs: the reserved CPU time spread over them.
    assert cluster_seconds(pieces, budget, 2) == pytest.approx(reserved / 2)
    # Many CPUs: the longest chain of pieces that wait for one another (dataset → π^s → its A3C run).
    chain = estimates["data"] + estimates["pretrain/STG1/policy-seed0"] + estimates["runs/STG1/pretrain-a3c-value/seed0"]
    chain = max(chain, estimates["data"] + estimates["pretrain/STG1/value-seed0"]
                + estimates["runs/STG1/pretrain-a3c-value/seed0"])
    assert cluster_seconds(pieces, budget, 10_000) == pytest.approx(chain)
    with pytest.raises(ValueError, match="needs CPUs"):
        cluster_seconds(pieces, budget, 0)


DATA = Path(__file__).parent / "data"


def test_a_flat_budget_stored_before_the_groups_loads_as_the_same_budget():
    """``quick`` as ``plan.json`` stored it when every setting was a field of the budget itself."""
    flat = json.loads((DATA / "quick_budget_flat.json").read_text())
    assert "dagger_episodes" in flat and "dagger" not in flat
    assert Budget.from_dict(flat) == BUDGETS["quick"]
    # Every flat name has its place; none is left over or lost.
    assert set(flat) == set(FLAT_FIELDS) | {"name", "tasks", "algorithms", "seeds", "obs", "threshold_fraction",
                                           "torch_threads"}
    with pytest.raises(ValueError, match=r"unknown budget settings \['dagger_rounds'\]; allowed: \['a3c', "):
        Budget.from_dict({**flat, "dagger_rounds": 3})
    with pytest.raises(ValueError, match=r"Budget.dagger.episodes twice: as 'dagger_episodes' and in 'dagger'"):
        Budget.from_dict({**flat, "dagger": {"episodes": 3}})


@pytest.mark.parametrize("name", list(BUDGETS))
def test_every_preset_survives_its_stored_form(name):
    budget = BUDGETS[name]
    stored = json.loads(json.dumps(budget.to_dict()))
    assert set(stored) == {f.name for f in dataclasses.fields(Budget)}
    assert stored["a3c"]["steps"] == dict(budget.a3c.steps) and stored["dataset"]["task"] == "FULL"
    assert Budget.from_dict(stored) == budget


def test_stored_groups_with_unknown_or_malformed_settings_are_refused_by_name():
    stored = BUDGETS["quick"].to_dict()
    with pytest.raises(ValueError, match=r"unknown budget settings of Budget.dagger \['rounds'\]; allowed: "
                                         r"\['episodes', 'epochs', 'eval_episodes', 'iterations'\]"):
        Budget.from_dict({**stored, "dagger": {**stored["dagger"], "rounds": 3}})
    with pytest.raises(ValueError, match=r"Budget.value must be a mapping of its settings, got 3"):
        Budget.from_dict({**stored, "value": 3})
    with pytest.raises(ValueError, match=r"Budget.network must be a NetworkBudget, got \{'hidden': 8\}"):
        dataclasses.replace(BUDGETS["quick"], network={"hidden": 8})


def test_replace_changes_only_the_named_fields_of_a_group():
    quick = BUDGETS["quick"]
    changed = quick.replace(seeds=1, dagger={"episodes": 3}, network=NetworkBudget(hidden=8))
    assert (changed.seeds, changed.dagger.episodes, changed.network.hidden) == (1, 3, 8)
    assert changed.dagger == dataclasses.replace(quick.dagger, episodes=3) and changed.a3c == quick.a3c
    assert quick.dagger.episodes == 6  # the preset itself is unchanged


# ------------------------------------------------------------------------------------------- PPO
def test_the_ppo_group_is_ppos_defaults_and_survives_its_stored_form():
    from bimgame.learn.ppo import PPOConfig, PPOOptimizationSettings

    quick = BUDGETS["quick"]
    defaults = PPOConfig().optimization
    # Every PPO optimisation setting is a field of the group, at PPO's own default.
    assert {f.name: getattr(quick.ppo, f.name) for f in dataclasses.fields(PPOOptimizationSettings)} == \
        dataclasses.asdict(defaults)
    assert quick.ppo.envs_per_worker == 16 and all(b.ppo == quick.ppo for b in BUDGETS.values())
    changed = quick.replace(ppo={"n_steps": 64, "sequence_length": 16, "lr": 1e-4})
    stored = json.loads(json.dumps(changed.to_dict()))
    assert stored["ppo"]["n_steps"] == 64 and Budget.from_dict(stored) == changed
    assert changed.settings_by_path()["ppo.sequence_length"] == 16


def test_a_nested_plan_stored_before_the_ppo_group_loads_with_ppos_defaults():
    for name, budget in BUDGETS.items():
        stored = json.loads(json.dumps(budget.to_dict()))
        del stored["ppo"]
        assert Budget.from_dict(stored) == budget, name


@pytest.mark.parametrize("changes, message", [
    ({"ppo": {"n_steps": 0}}, r"Budget.ppo.n_steps must be an integer >= 1, got 0$"),
    ({"ppo": {"envs_per_worker": 0}}, r"Budget.ppo.envs_per_worker must be an integer >= 1, got 0$"),
    ({"ppo": {"sequence_length": 7}}, r"Budget.ppo.sequence_length must divide n_steps \(128\) or be None, got 7$"),
    ({"ppo": {"minibatches": 256}}, r"Budget.ppo.minibatches must be at most the sequences of a rollout \(128: "),
    ({"ppo": {"clip": 0.0}}, r"Budget.ppo.clip must be "),
    ({"obs": "pixels", "algorithms": ("a3c", "ppo"), "a3c": {"augment_shift": 2}},
     r"Budget.a3c.augment_shift 2 with ppo in the grid: PPO's runs have no random shifts.*leave ppo out"),
])
def test_bad_ppo_settings_are_rejected_by_their_path(changes, message, tiny_budget):
    with pytest.raises(ValueError, match=message):
        tiny_budget.replace(**changes)
    with pytest.raises(ValueError, match=r"unknown budget settings of Budget.ppo \['epoch'\]; allowed: \["):
        Budget.from_dict({**tiny_budget.to_dict(), "ppo": {"epoch": 3}})


def test_ppo_runs_share_the_a3c_runs_steps_and_pi_s_and_cost_their_own_speed():
    quick = BUDGETS["quick"].with_grid(algorithms=["a3c", "pretrain+a3c", "ppo", "pretrain+ppo"])
    pieces = {p.id: p for p in plan_pieces(quick)}
    # One π^s per task and seed, read by both learners' pre-trained runs.
    assert [i for i in pieces if i.startswith("pretrain/")] == ["pretrain/STG1/policy-seed0", "pretrain/STG1/policy-seed1"]
    ppo, pretrained = pieces["runs/STG1/ppo/seed0"], pieces["runs/STG1/pretrain-ppo/seed0"]
    assert (ppo.kind, ppo.needs) == ("ppo", ()) and pretrained.needs == ("pretrain/STG1/policy-seed0",)
    assert pieces["runs/STG1/pretrain-a3c/seed0"].needs == pretrained.needs
    # PPO: one process at about a quarter of A3C's speed with two workers, plus its evaluations.
    a3c_seconds = estimate_seconds(pieces["runs/STG1/a3c/seed0"], quick)
    ppo_seconds = estimate_seconds(ppo, quick)
    assert 3 * a3c_seconds < ppo_seconds < 5 * a3c_seconds
    assert piece_cpus(ppo, quick) == quick.torch_threads == 1 and piece_cpus(pieces["runs/STG1/a3c/seed0"], quick) == 3
    assert estimate_seconds(ppo, quick.replace(a3c={"eval_every": 0})) < ppo_seconds  # evaluations stop it
    assert kind_of(ppo).resumable  # a cluster ships its checkpoints home, as an A3C run's
