"""Tests of the start curriculum a learner's settings ask for (bimgame.learn.curricula): the right
curriculum for each puzzle and kind, PPO's settings take it as A3C's do, and a PPO rank's collector
samples from it."""

from __future__ import annotations

import pytest

from bimgame.learn.a3c import A3CConfig
from bimgame.learn.curricula import CURRICULUM_COLUMNS, start_curriculum
from bimgame.learn.learner_settings import CurriculumSettings
from bimgame.learn.ppo import PPOConfig
from bimgame.learn.ppo.learner import RankLearner, adam
from bimgame.learn.learner_settings import policy_network
from bimgame.learn.starts import DemoStartCurriculum, ReverseCurriculum

TINY = dict(task="STG1", obs="state", hidden=16, features=16, envs_per_worker=4, n_steps=16, steps=64)


def test_each_kind_on_the_maze(stg1_dataset):
    assert isinstance(start_curriculum("STG2", CurriculumSettings("reverse")), ReverseCurriculum)
    demo = start_curriculum("STG1", CurriculumSettings("demo", 0.7), stg1_dataset)
    assert isinstance(demo, DemoStartCurriculum) and demo.threshold == 0.7
    with pytest.raises(ValueError, match="start_curriculum 'demo' needs expert_data"):
        start_curriculum("STG1", CurriculumSettings("demo"))
    for curriculum in (demo, start_curriculum("STG2", CurriculumSettings("reverse"))):
        assert set(curriculum.status()) <= set(CURRICULUM_COLUMNS)  # every status key has its log column
    with pytest.raises(ValueError, match="start_curriculum 'demo-uniform' needs expert_data"):
        start_curriculum("STG1", CurriculumSettings("demo-uniform"))


def test_uniform_demonstration_starts_reach_back_over_every_state_of_the_maze_from_the_first_episode(stg1_dataset):
    """``demo-uniform`` is one stage holding the whole of every expert episode; ``demo`` starts near the goal."""
    demo = start_curriculum("STG1", CurriculumSettings("demo"), stg1_dataset)
    uniform = start_curriculum("STG1", CurriculumSettings("demo-uniform", 0.7), stg1_dataset)
    assert isinstance(uniform, DemoStartCurriculum) and uniform.threshold == 0.7
    longest = uniform.stages.longest
    assert uniform.stages.back == longest > 30 == demo.stages.back
    assert len(uniform.stages.backs) == 1 < len(demo.stages.backs)


def test_ppo_settings_take_the_curriculum_as_a3cs_do(stg1_dataset):
    for config in (A3CConfig, PPOConfig):
        name = config.__name__
        assert config.from_flat(TINY).curriculum is None
        reverse = config.from_flat(TINY, start_curriculum="reverse", curriculum_threshold=0.6)
        assert reverse.curriculum == CurriculumSettings("reverse", 0.6)
        assert config.from_dict(reverse.to_dict()) == reverse
        with pytest.raises(ValueError, match=rf"{name}\.start_curriculum='demo' needs expert_data"):
            config.from_flat(TINY, start_curriculum="demo")
        demo = config.from_flat(TINY, start_curriculum="demo", expert_data=str(stg1_dataset))
        assert demo.curriculum.start_curriculum == "demo"
        with pytest.raises(ValueError, match=rf"{name}\.start_curriculum='demo-uniform' needs expert_data"):
            config.from_flat(TINY, start_curriculum="demo-uniform")
        assert (
            CurriculumSettings("demo-uniform").reads_demonstrations
            and not CurriculumSettings("reverse").reads_demonstrations
        )
        with pytest.raises(ValueError, match=r"CurriculumSettings\.start_curriculum must be one of"):
            config.from_flat(TINY, start_curriculum="forward")


def test_a_ppo_ranks_episodes_start_from_the_curriculum():
    config = PPOConfig.from_flat(TINY, start_curriculum="reverse")
    net = policy_network(config)
    episodes = []
    learner = RankLearner(config, net, adam(net, config), rank=0, step=0, on_episode=episodes.append,
                          global_step=lambda: 0)
    assert isinstance(learner.collector.curriculum, ReverseCurriculum)
    for step in range(0, 1600, 64):
        learner.rollout_and_update(step)
    assert episodes and any(not episode.true_start for episode in episodes)
    assert set(learner.curriculum_status()) <= set(CURRICULUM_COLUMNS)
