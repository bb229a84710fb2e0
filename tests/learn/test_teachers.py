"""A trained state policy as a teacher (bimgame.learn.teachers): the state teacher reads, from the state a
learner's envs record, exactly the observation its own env gives (surroundings included), so its policy
over a segment is the one it has acting on its own observations; a teacher that cannot teach the
learner is refused by name."""

from __future__ import annotations

import pytest
import torch

from bimgame.cli.main import main
from bimgame.learn.actor import RecurrentActor
from bimgame.learn.common import load_run_network
from bimgame.learn.finetune import Teacher
from bimgame.learn.rollout import RolloutCollector, training_env
from bimgame.learn.teachers import StateTeacher, load_labyrinth_teacher
from support.labyrinth_runs import SMALL_STATE_FLAGS

TASK = "LABYRINTH-EASY"

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _segment_on_own_observations(teacher_run, steps: int = 40):
    """A segment of the teacher acting (sampled) on two envs of its own observation (state with
    surroundings) that also record the state; episodes of 15 steps, so that some start mid-segment."""
    net, run, _ = load_run_network(teacher_run)
    env = training_env(2, task=TASK, obs="state", time_limit=15, privileged=True, action_type="continuous",
                       surroundings=True)
    actor = RecurrentActor(net, 2, generator=torch.Generator().manual_seed(0))
    collector = RolloutCollector(env, env, actor, gamma=0.99, tilt_input=run.network.tilt_input, privileged=True)
    collector.reset(seed=0, step=0)
    segment = collector.collect(steps, 0)
    env.close()
    return net, segment


def test_the_state_teacher_sees_what_its_own_env_shows_and_follows_as_it_acts(surroundings_teacher_run):
    net, segment = _segment_on_own_observations(surroundings_teacher_run)
    assert segment.starts[1:].any()  # an episode started inside the segment: the LSTM is reset there
    teacher = StateTeacher(surroundings_teacher_run, TASK, "continuous", learner_tilt_input=True, batch=2)
    # The 17 recorded state values with the surroundings computed from them: the env's own 33 values.
    assert segment.privileged is not None and segment.privileged.shape[-1] == 17
    torch.testing.assert_close(teacher.observations(segment.privileged), segment.obs)
    # Following the segment from the recorded state alone (the observations replaced by a learner's
    # others) gives the teacher's policy on its own observations, across two segments (its LSTM carries).
    own = Teacher(net, 2)
    blind = segment.replace(obs=torch.zeros(*segment.obs.shape[:2], 5))
    for _ in range(2):
        torch.testing.assert_close(teacher.follow(blind), own.follow(segment))
    with pytest.raises(ValueError, match="Segment.privileged"):
        teacher.follow(segment.replace(privileged=None))


def test_a_teacher_that_cannot_teach_the_learner_is_refused_by_name(surroundings_teacher_run, tmp_path):
    with pytest.raises(ValueError, match="trained on LABYRINTH-EASY, the learner runs on LABYRINTH-HARD"):
        load_labyrinth_teacher(surroundings_teacher_run, "LABYRINTH-HARD", "continuous", "owner")
    with pytest.raises(ValueError, match="owner .* acts with continuous actions, the learner with discrete"):
        load_labyrinth_teacher(surroundings_teacher_run, TASK, "discrete", "owner")
    with pytest.raises(ValueError, match="on the labyrinth, not on STG1"):
        load_labyrinth_teacher(surroundings_teacher_run, "STG1", "continuous", "owner")
    with pytest.raises(ValueError, match="does not exist"):
        StateTeacher(tmp_path / "missing", TASK, "continuous", learner_tilt_input=True, batch=1)
    with pytest.raises(ValueError, match="reads the tilt input.*tilt_input true"):
        StateTeacher(surroundings_teacher_run, TASK, "continuous", learner_tilt_input=False, batch=1)
    # A policy of another observation cannot read the recorded state.
    cyberrunner = tmp_path / "cyberrunner"
    flags = [*SMALL_STATE_FLAGS]
    flags[flags.index("--obs") + 1] = "cyberrunner"
    assert main(["train", "--algo", "ppo", "--run-dir", str(cyberrunner), "--steps", "64", *flags]) == 0
    with pytest.raises(ValueError, match="observes 'cyberrunner'.*obs 'state'"):
        StateTeacher(cyberrunner, TASK, "continuous", learner_tilt_input=True, batch=1)
