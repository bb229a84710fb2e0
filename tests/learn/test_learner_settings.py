"""A3C's settings in parts (:mod:`bimgame.learn.learner_settings`, :class:`~bimgame.learn.a3c.A3CConfig`):
flat names in and out, the optional parts, config.json files an earlier version wrote, and each part's
own checks."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import bimgame.learn.a3c as a3c
from bimgame.learn.a3c import A3CConfig, network_for
from bimgame.learn.a3c.settings import OptimizationSettings
from bimgame.learn.common import NetworkSettings
from bimgame.learn.learner_settings import (
    FINETUNE_FIELDS,
    FINETUNE_PRESETS,
    MAX_STEPS,
    START_CURRICULA,
    CurriculumSettings,
    FinetuneSettings,
    ScheduleSettings,
)

DATA = Path(__file__).parent / "data"
#: The config.json of an A3C run fine-tuned with the ``keep`` preset, byte for byte as the version
#: before the settings had parts (commit 8597f1b, one flat ``A3CConfig``) wrote it.
OLD_CONFIG = DATA / "old_a3c_config.json"

SMALL = dict(task="STG1", obs="state", hidden=16, features=16)
#: The fine-tuning settings of the keep preset (the preset also names start_curriculum: no curriculum).
KEEP = {k: v for k, v in FINETUNE_PRESETS["keep"].items() if k != "start_curriculum"}


def _from_scratch() -> A3CConfig:
    return A3CConfig.from_flat(SMALL, lr=1e-3, steps=4_000, workers=1, seed=7)


def _keep() -> A3CConfig:
    return A3CConfig.from_flat(SMALL, finetune="keep", **FINETUNE_PRESETS["keep"])


def _reverse() -> A3CConfig:
    return A3CConfig.from_flat(SMALL, start_curriculum="reverse", curriculum_threshold=0.6)


# ------------------------------------------------------------------------------ flat names


@pytest.mark.parametrize("make", [_from_scratch, _keep, _reverse], ids=["scratch", "keep", "reverse"])
def test_flat_names_round_trip(make):
    config = make()
    flat = config.to_dict()
    assert list(flat) == list(A3CConfig.flat_names())  # every setting, each once
    rebuilt = A3CConfig.from_flat(flat)
    assert rebuilt == config and rebuilt.to_dict() == flat
    assert A3CConfig.from_dict(json.loads(json.dumps(flat))) == config  # through config.json's JSON
    assert config.with_flat() == config


def test_flat_names_go_to_their_parts():
    scratch = _from_scratch()
    assert scratch.network == NetworkSettings(obs="state", hidden=16, features=16)
    assert scratch.optimization == OptimizationSettings(lr=1e-3)
    assert scratch.schedule == ScheduleSettings(steps=4_000, workers=1)
    assert (scratch.task, scratch.seed, scratch.finetuning, scratch.curriculum) == ("STG1", 7, None, None)
    keep = _keep()
    assert keep.finetuning == FinetuneSettings(finetune="keep", **KEEP) and keep.curriculum is None
    assert keep.has_teacher and keep.schedules_actor
    reverse = _reverse()
    assert reverse.curriculum == CurriculumSettings(start_curriculum="reverse", curriculum_threshold=0.6)
    assert reverse.finetuning is None and not reverse.has_teacher and not reverse.schedules_actor
    assert reverse.to_dict()["start_curriculum"] == "reverse"
    # Without a curriculum part the flat value says so.
    assert scratch.to_dict()["start_curriculum"] == "none" and "none" in START_CURRICULA


def test_with_flat_changes_a_setting_in_its_part_and_keeps_the_rest():
    config = _keep()
    changed = config.with_flat(lr=5e-4, steps=9_000, kl_coef=0.0)
    assert changed.optimization == OptimizationSettings(lr=5e-4)
    assert changed.schedule.steps == 9_000 and changed.network == config.network
    assert changed.finetuning == FinetuneSettings(finetune="keep", **{**KEEP, "kl_coef": 0.0})
    assert not changed.has_teacher and config.has_teacher  # the original is unchanged
    assert config.with_flat(start_curriculum="reverse").curriculum == CurriculumSettings(start_curriculum="reverse")


def test_unknown_flat_names_are_refused_by_name():
    with pytest.raises(ValueError, match=r"unknown A3C settings \['learning_rate'\]; allowed: \[.*'lr'"):
        A3CConfig.from_flat(SMALL, learning_rate=1e-3)
    with pytest.raises(ValueError, match=r"unknown A3C settings \['hiden', 'wokers'\]"):
        A3CConfig.from_dict({**_from_scratch().to_dict(), "wokers": 3, "hiden": 8})
    with pytest.raises(ValueError, match=r"unknown A3C settings \['gama'\]"):
        _from_scratch().with_flat(gama=0.9)
    # A part's field name is not a flat name.
    with pytest.raises(ValueError, match=r"unknown A3C settings \['network'\]"):
        A3CConfig.from_flat(network=NetworkSettings())


def test_derived_values():
    config = A3CConfig.from_flat(SMALL, n_steps=10, envs_per_worker=4)
    assert config.steps_per_update == 40 and config.time_limit == 300  # STG1's own limit
    assert config.with_flat(max_episode_steps=123).time_limit == 123


def test_the_shared_names_are_importable_from_the_a3c_package():
    assert a3c.START_CURRICULA is START_CURRICULA
    assert a3c.MAX_STEPS == MAX_STEPS == 10**12
    assert FINETUNE_FIELDS == tuple(FINETUNE_PRESETS["paper"])
    assert set(FINETUNE_FIELDS) <= set(A3CConfig.flat_names())


# ------------------------------------------------------------------------------ optional parts

#: A non-default value of each fine-tuning setting (bc_coef needs expert data).
NOT_DEFAULT = {"finetune": "paper", "critic_warmup_steps": 1, "actor_ramp_steps": 1, "kl_coef": 0.1,
               "kl_decay_steps": 1, "kl_temperature": 0.5, "advantage_norm": True, "bc_coef": 0.1,
               "bc_decay_steps": 1}


def test_every_fine_tuning_setting_has_a_non_default_value_here():
    defaults = FinetuneSettings()
    assert set(NOT_DEFAULT) == {f for f in A3CConfig.flat_names() if hasattr(defaults, f)}
    assert all(getattr(defaults, name) != value for name, value in NOT_DEFAULT.items())


@pytest.mark.parametrize("name", list(NOT_DEFAULT))
def test_a_fine_tuning_part_exactly_when_a_fine_tuning_setting_is_not_its_default(name):
    config = A3CConfig.from_flat(SMALL, expert_data="data", **{name: NOT_DEFAULT[name]})
    assert config.finetuning is not None and getattr(config.finetuning, name) == NOT_DEFAULT[name]
    assert config.finetuning == FinetuneSettings(**{name: NOT_DEFAULT[name]})
    # Back at its default: no part.
    assert config.with_flat(**{name: getattr(FinetuneSettings(), name)}).finetuning is None


def test_no_fine_tuning_part_when_every_fine_tuning_setting_is_at_its_default():
    defaults = {name: getattr(FinetuneSettings(), name) for name in NOT_DEFAULT}
    assert A3CConfig.from_flat(SMALL, **defaults).finetuning is None
    assert A3CConfig.from_flat(SMALL).finetuning is None
    # A part given at its defaults is a run from scratch too: one config, not two equal-looking ones.
    given = A3CConfig(network=NetworkSettings(obs="state"), finetuning=FinetuneSettings())
    assert given.finetuning is None and given == A3CConfig.from_flat(obs="state")
    # The paper preset turns every term off but names itself: a fine-tuning part.
    paper = A3CConfig.from_flat(SMALL, finetune="paper", **FINETUNE_PRESETS["paper"])
    assert paper.finetuning == FinetuneSettings(finetune="paper") and not paper.finetuning.changes_nothing
    assert not paper.has_teacher and not paper.schedules_actor


def test_a_curriculum_part_exactly_when_a_start_curriculum_is_chosen():
    assert A3CConfig.from_flat(SMALL, start_curriculum="none").curriculum is None
    # Without a curriculum its threshold means nothing: it is dropped, and written back as the default.
    dropped = A3CConfig.from_flat(SMALL, start_curriculum="none", curriculum_threshold=0.5)
    assert dropped.curriculum is None and dropped.to_dict()["curriculum_threshold"] == 0.8
    demo = A3CConfig.from_flat(SMALL, start_curriculum="demo", expert_data="data")
    assert demo.curriculum == CurriculumSettings(start_curriculum="demo")
    with pytest.raises(ValueError, match=r"A3CConfig.start_curriculum='demo' needs expert_data"):
        A3CConfig.from_flat(SMALL, start_curriculum="demo")
    with pytest.raises(ValueError, match=r"A3CConfig.bc_coef needs expert_data"):
        A3CConfig.from_flat(SMALL, bc_coef=0.1)


# ------------------------------------------------------------------------------ stored runs


def test_a_config_json_of_the_flat_version_loads_into_the_expected_parts():
    stored = json.loads(OLD_CONFIG.read_text())
    assert stored["kind"] == "a3c" and "network" not in stored["a3c"]  # flat names only
    config = A3CConfig.from_dict(stored["a3c"])
    assert (config.task, config.seed, config.max_episode_steps, config.randomize, config.expert_data) == (
        "STG2", 3, None, None, None)
    assert config.network == NetworkSettings(obs="state", hidden=128, features=128, precision="fp32")
    assert config.optimization == OptimizationSettings(lr=3e-4)
    assert config.schedule == ScheduleSettings(steps=2_000_000, workers=4, eval_every=50_000)
    assert config.finetuning == FinetuneSettings(finetune="keep", **KEEP)
    assert config.curriculum is None
    assert config.has_teacher and config.schedules_actor and config.time_limit == 500
    # Written back, it is the same record (with the settings added since at their defaults); its network
    # is the one the run stored.
    added = {"action_type": "discrete"}
    settings_added = {**added, "maze_encoding": False, "maze_frame": "board", "gate_bearings": False,
                      "surroundings": False, "motion": False,
                      "num_mazes": None,
                      "start_maze": 0, "off_path_rule": None, "fail_reward": None}
    assert config.to_dict() == {**stored["a3c"], **settings_added}
    assert json.loads(json.dumps(network_for(config).config.to_dict())) == {**stored["net"], **added, "maze_size": 0,
                                                                       "maze_frame": "board", "state_layout": "maze"}


# ------------------------------------------------------------------------------ each part's checks


@pytest.mark.parametrize("make, message", [
    (lambda: ScheduleSettings(workers=0), r"ScheduleSettings\.workers must be an integer >= 1, got 0"),
    (lambda: ScheduleSettings(steps=MAX_STEPS + 1), r"ScheduleSettings\.steps must be at most 1,000,000,000,000"),
    (lambda: ScheduleSettings(eval_every=-1), r"ScheduleSettings\.eval_every must be an integer >= 0"),
    (lambda: ScheduleSettings(envs_per_worker=5000), r"ScheduleSettings\.envs_per_worker must be at most 4,096"),
    (lambda: OptimizationSettings(lr=0.0), r"OptimizationSettings\.lr must be a finite number > 0, got 0.0"),
    (lambda: OptimizationSettings(gamma=1.5), r"OptimizationSettings\.gamma must be in \[0.0, 1.0\], got 1.5"),
    (lambda: OptimizationSettings(optimizer="sgd"), r"OptimizationSettings\.optimizer must be one of"),
    (lambda: OptimizationSettings(augment_shift=99), r"OptimizationSettings\.augment_shift must be 0\.\.\d+ pixels"),
    (lambda: OptimizationSettings(entropy_target=2.0), r"OptimizationSettings\.entropy_target must be None or in"),
    (lambda: FinetuneSettings(finetune="forget"), r"FinetuneSettings\.finetune must be None or one of"),
    (lambda: FinetuneSettings(kl_temperature=0), r"FinetuneSettings\.kl_temperature must be a finite number > 0"),
    (lambda: FinetuneSettings(critic_warmup_steps=-1), r"FinetuneSettings\.critic_warmup_steps must be an integer"),
    (lambda: FinetuneSettings(advantage_norm=1), r"FinetuneSettings\.advantage_norm must be True or False"),
    (lambda: CurriculumSettings(start_curriculum="none"), r"CurriculumSettings\.start_curriculum must be one of"),
    (lambda: CurriculumSettings(curriculum_threshold=0), r"CurriculumSettings\.curriculum_threshold must be in"),
    (lambda: NetworkSettings(hidden=5000), r"NetworkSettings\.hidden must be at most 4096"),
])
def test_each_part_validates_alone(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize("flat, message", [
    ({"workers": 0}, r"ScheduleSettings\.workers must be an integer >= 1, got 0"),
    ({"lr": float("nan")}, r"OptimizationSettings\.lr must be a finite number > 0"),
    ({"kl_temperature": -1.0}, r"FinetuneSettings\.kl_temperature"),
    ({"start_curriculum": "reverse", "curriculum_threshold": 2.0}, r"CurriculumSettings\.curriculum_threshold"),
    ({"curriculum_threshold": 2.0}, r"CurriculumSettings\.curriculum_threshold"),  # checked without a curriculum too
    ({"hidden": 0}, r"NetworkSettings\.hidden"),
    ({"augment_shift": 2}, r"A3CConfig\.augment_shift must be 0\.\.\d+ pixels, and 0 for state observations"),
    ({"task": "STG9"}, r"A3CConfig\.task"),
])
def test_a3c_config_from_flat_names_raises_the_parts_errors(flat, message):
    with pytest.raises(ValueError, match=message):
        A3CConfig.from_flat(SMALL, **flat)


def test_parts_of_the_wrong_type_are_refused():
    with pytest.raises(ValueError, match=r"A3CConfig\.schedule must be a ScheduleSettings, got"):
        A3CConfig(schedule={"steps": 10})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"A3CConfig\.finetuning must be None or a FinetuneSettings, got"):
        A3CConfig(finetuning=CurriculumSettings())  # type: ignore[arg-type]
