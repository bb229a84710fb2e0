"""The algorithm registry: one record per algorithm is all a reproduction needs of it. A test registers
an algorithm of its own — A3C without the entropy bonus — and runs a tiny grid and its report with
it, through the real pieces; unknown names fail listing the registered ones."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator

import pytest

from bimgame.experiments.algorithms import (
    Algorithm,
    Learner,
    algorithm_named,
    algorithm_names,
    register,
    registered,
    unregister,
)
from bimgame.experiments.budgets import ALGORITHM_LABELS, ALGORITHMS, PAPER_ALGORITHMS, Budget
from bimgame.experiments.grid import plan_pieces
from bimgame.experiments.kinds import KINDS, kind_of, run_kind
from bimgame.experiments.methods import finetune_overrides, needs_expert_data
from bimgame.experiments.plan import load_plan, load_status
from bimgame.experiments.report import build_report
from bimgame.experiments.reproduce import reproduce
from bimgame.experiments.runners import a3c_config_for, ppo_config_for
from bimgame.learn.curves import read_table
from bimgame.learn.ppo import train_ppo

NAME, LABEL = "a3c+beta0", "A3C (β=0)"


@pytest.fixture
def beta0() -> Iterator[Algorithm]:
    """A3C from random weights with no entropy bonus, registered for the test only."""
    record = register(Algorithm(NAME, LABEL, settings=lambda steps: {"entropy_coef": 0.0}))
    try:
        yield record
    finally:
        unregister(NAME)


def test_the_built_in_records_are_what_the_budget_and_the_labels_show():
    assert algorithm_names() == ALGORITHMS
    assert dict(ALGORITHM_LABELS) == {name: algorithm_named(name).label for name in ALGORITHMS}
    assert algorithm_named("dagger").learner is Learner.DAGGER
    assert algorithm_named("pretrain+a3c+value").starts_from_policy and algorithm_named("a3c+value").value_reward
    assert not algorithm_named("a3c").starts_from_policy and not algorithm_named("a3c").value_reward


def test_an_unknown_algorithm_is_an_error_listing_the_registered_ones():
    with pytest.raises(ValueError, match=r"unknown algorithm 'a3c\+nope'; registered: a3c, pretrain\+a3c, "):
        algorithm_named("a3c+nope")
    with pytest.raises(ValueError, match=r"Budget\.algorithms: unknown \['a3c\+nope'\]; allowed: a3c, "):
        Budget(algorithms=("a3c", "a3c+nope"))
    with pytest.raises(ValueError, match="registered already"):
        register(Algorithm("a3c", "another A3C"))
    with pytest.raises(ValueError, match=r"dagger\+init: dagger runs take no starts_from_policy; what each "
                                         r"learner's runs take — a3c: settings, starts_from_policy, value_reward; "
                                         r"ppo: settings, starts_from_policy; dagger: none$"):
        Algorithm("dagger+init", "DAgger from π^s", learner=Learner.DAGGER, starts_from_policy=True)
    with pytest.raises(ValueError, match=r"ppo\+value: ppo runs take no value_reward; "):
        Algorithm("ppo+value", "PPO + value reward", learner=Learner.PPO, value_reward=True)


def test_a_registered_algorithm_is_in_the_labels_budgets_and_grid_until_it_is_removed(beta0):
    assert ALGORITHM_LABELS[NAME] == LABEL and algorithm_names()[-1] == NAME
    assert finetune_overrides(NAME, 1_000, None) == {"entropy_coef": 0.0} and not needs_expert_data(NAME)
    budget = Budget(tasks=("STG1",), algorithms=(NAME, "a3c"), seeds=1)
    assert budget.algorithms == ("a3c", NAME)  # the registry's order
    assert [p.path for p in plan_pieces(budget) if p.algorithm == NAME] == ["runs/STG1/a3c-beta0/seed0"]
    unregister(NAME)
    try:
        assert NAME not in ALGORITHM_LABELS
        with pytest.raises(ValueError, match="unknown"):
            Budget(algorithms=(NAME,))
    finally:
        register(beta0)


def test_a_tiny_grid_with_a_registered_algorithm_runs_and_reports_it(tmp_path, tiny_budget, beta0):
    # One short run of the new algorithm (the grid's other pieces are the kinds the other tests run).
    budget = tiny_budget.replace(algorithms=(NAME,), seeds=1, a3c={"steps": {"STG1": 800}})
    result = reproduce(tmp_path, budget, progress=False)
    assert result.complete and result.computed == ["data", "runs/STG1/a3c-beta0/seed0"]
    assert load_plan(tmp_path)[0].algorithms == (NAME,)
    stored = json.loads((tmp_path / "runs/STG1/a3c-beta0/seed0/config.json").read_text())
    assert stored["a3c"]["entropy_coef"] == 0.0 and stored["init"] is None
    assert a3c_config_for(budget, "STG1", 0, "a3c").optimization.entropy_coef == 0.01  # A3C's own is unchanged

    paths = build_report(tmp_path, resamples=100)
    numbers = json.loads(paths.table_json.read_text())["tasks"]["STG1"]["algorithms"]
    assert numbers[NAME]["seeds_finished"] == 1 and numbers[NAME]["runs"][0]["dir"] == "runs/STG1/a3c-beta0/seed0"
    assert LABEL in paths.table_md.read_text() and LABEL in paths.report.read_text()
    assert f"| {LABEL} | 1/1 |" in paths.report.read_text()  # its row of the speed-up table
    assert (tmp_path / "fig_curves_STG1.png").is_file()


def test_a_tiny_grid_with_ppo_from_scratch_and_from_pi_s_runs_resumes_and_reports_them(tmp_path, tiny_budget):
    """Both PPO algorithms through the real pieces: π^s pre-trained once and read by ``pretrain+ppo``,
    an unfinished PPO run continued from its checkpoint, and both in the report's tables and figures."""
    budget = tiny_budget.replace(algorithms=("ppo", "pretrain+ppo", "pretrain+ppo+keep"), seeds=1,
                                 a3c={"steps": {"STG1": 512}, "eval_every": 256, "checkpoint_every": 128},
                                 ppo={"envs_per_worker": 4, "n_steps": 32})
    first = reproduce(tmp_path, budget, progress=False, stop_after=2)
    assert first.computed == ["data", "pretrain/STG1/policy-seed0"]
    # A PPO run stopped half-way: the reproduction continues it from its checkpoint.
    partial = tmp_path / "runs/STG1/ppo/seed0"
    train_ppo(ppo_config_for(budget, "STG1", 0, "ppo").with_flat(steps=256), partial, progress=False)
    result = reproduce(tmp_path, budget, progress=False)
    assert result.complete and result.computed == [
        "runs/STG1/ppo/seed0", "runs/STG1/pretrain-ppo/seed0", "runs/STG1/pretrain-ppo-keep/seed0"]
    keep = json.loads((tmp_path / "runs/STG1/pretrain-ppo-keep/seed0/config.json").read_text())["ppo"]
    assert (keep["kl_coef"], keep["kl_temperature"]) == (0.2, 0.3)  # the keep preset's KL, read from it
    assert (tmp_path / "runs/STG1/pretrain-ppo-keep/seed0/teacher.pt").is_file()
    assert load_status(tmp_path)["pieces"]["runs/STG1/ppo/seed0"]["note"] == "resumed from its checkpoint"
    for slug, init in (("ppo", None), ("pretrain-ppo", str((tmp_path / "pretrain/STG1/policy-seed0").resolve()))):
        run = tmp_path / "runs/STG1" / slug / "seed0"
        stored = json.loads((run / "config.json").read_text())
        assert stored["kind"] == "ppo" and stored["init"] == init
        assert (stored["ppo"]["envs_per_worker"], stored["ppo"]["n_steps"], stored["ppo"]["eval_every"]) == (4, 32, 256)
        summary = json.loads((run / "summary.json").read_text())
        assert (summary["steps"], summary["stopped"], summary["final_eval"]["step"]) == (512, "finished", 512)
        evaluations = read_table(run / "eval.csv")["step"]
        assert evaluations[-1] == 512 and (slug == "ppo" or 256 in evaluations)  # every eval_every steps
    assert reproduce(tmp_path, budget, progress=False).computed == []  # finished: nothing to do

    paths = build_report(tmp_path, resamples=100)
    numbers = json.loads(paths.table_json.read_text())["tasks"]["STG1"]["algorithms"]
    for name, label in (("ppo", "PPO"), ("pretrain+ppo", "pre-train + PPO")):
        assert numbers[name]["seeds_finished"] == 1 and numbers[name]["runs"][0]["env_steps"] == 512
        assert f"| {label} | 1/1 |" in paths.report.read_text() and label in paths.table_md.read_text()
    assert (tmp_path / "fig_curves_STG1.png").is_file()


def test_the_records_say_what_the_names_used_to():
    policy = [a.name for a in registered() if a.starts_from_policy]
    assert policy == [a for a in ALGORITHMS if a.startswith("pretrain")]
    assert [a.name for a in registered() if a.value_reward] == ["a3c+value", "pretrain+a3c+value"]
    assert [a.name for a in registered() if a.learner is Learner.DAGGER] == ["dagger"]
    assert {a.name: a.without_value_reward for a in registered() if a.without_value_reward} == {
        "a3c+value": "a3c", "pretrain+a3c+value": "pretrain+a3c"}
    assert [a.name for a in registered() if a.paper] == list(PAPER_ALGORITHMS)
    assert algorithm_named("pretrain+a3c+value").slug == "pretrain-a3c-value"
    for algorithm in registered():
        assert run_kind(algorithm).name == algorithm.learner.value
    assert set(KINDS) == {"dataset", "pretrain-policy", "pretrain-value", "a3c", "dagger", "ppo"}
    assert [a.name for a in registered() if a.learner is Learner.PPO] == ["ppo", "pretrain+ppo", "pretrain+ppo+keep"]


def test_bad_records_and_kinds_are_refused_naming_what_is_allowed():
    with pytest.raises(ValueError, match=r"without_value_reward 'a3c\+nothing' is not registered"):
        register(Algorithm("a3c+nothing+value", "?", value_reward=True, without_value_reward="a3c+nothing"))
    with pytest.raises(ValueError, match=r"Algorithm.learner must be one of"):
        Algorithm("ppo", "PPO", learner="ppo")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"unknown piece kind 'sac'; allowed: dataset, pretrain-policy, "
                                         r"pretrain-value, a3c, dagger, ppo$"):
        kind_of(dataclasses.replace(plan_pieces(Budget(algorithms=("a3c",)))[0], kind="sac"))
