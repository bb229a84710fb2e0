"""Trained labyrinth policies as teachers of other learners, and the privileged one PPO kickstarts from.

A policy trained on the labyrinth's simulator state (PPO from state completes the easy layout in
≈ 80% of episodes) can teach a learner that observes less (pixels): DAgger asks it for labels
(:class:`~bimgame.learn.dagger.teacher.PolicyTeacher`), and PPO can pull its learner towards it with
kickstarting's KL (Schmitt et al. 2018) on the learner's own rollouts (:class:`StateTeacher`) — the
privileged teacher of "Learning by Cheating" (Chen et al., CoRL 2019) used inside RL rather than
before it. :func:`load_labyrinth_teacher` loads either and refuses a teacher of another layout or
another kind of action.

:class:`StateTeacher` reads the state the learner's envs record anyway (``Segment.privileged``: the
17 state values, for auxiliary heads and an asymmetric critic) and adds the holes and walls around
the marble (:class:`~bimgame.envs.labyrinth_surroundings.Surroundings`, a function of the marble's
position) when the teacher reads them: its observation is then exactly what its own env would
have returned in the same simulator state, with no second simulation and nothing re-rendered.
"""

from __future__ import annotations

from pathlib import Path

import torch

from bimgame.envs.labyrinth_surroundings import Surroundings
from bimgame.envs.puzzles import puzzle
from bimgame.learn.common import RunInfo, load_run_network
from bimgame.learn.finetune import Teacher
from bimgame.learn.nets import RecurrentActorCritic
from bimgame.learn.rollout import Segment
from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = ["StateTeacher", "load_labyrinth_teacher"]


def load_labyrinth_teacher(
    source: str | Path, task: str, action_type: str, owner: str
) -> tuple[RecurrentActorCritic, RunInfo]:
    """The policy network and run of ``source`` (a run directory or a checkpoint in one), checked to
    teach a learner on ``task`` with ``action_type`` actions: the labyrinth, the same layout, the same
    kind of action. ``owner`` names the setting in the errors (e.g. ``DAggerConfig.teacher``)."""
    net, run, _ = load_run_network(source)
    learner_puzzle, teacher_puzzle = puzzle(task), puzzle(run.task)
    if learner_puzzle.is_maze:
        raise ValueError(f"{owner}: a learned teacher teaches on the labyrinth, not on {task}")
    if teacher_puzzle.task != learner_puzzle.task:
        raise ValueError(
            f"{owner} {source} was trained on {teacher_puzzle.task}, the learner runs on "
            f"{learner_puzzle.task}: a teacher teaches the layout it learned"
        )
    if run.network.action_type != action_type:
        raise ValueError(
            f"{owner} {source} acts with {run.network.action_type} actions, the learner with "
            f"{action_type}: a teacher must act with the learner's kind of action"
        )
    return net, run


class StateTeacher:
    """A policy trained on the labyrinth's state (``source``: its run or a checkpoint in one),
    following a learner's ``batch`` environments of ``task`` through the state they record: the
    kickstarting teacher of a learner that observes something else (pixels, CyberRunner's).

    ``follow`` gives what :meth:`~bimgame.learn.finetune.Teacher.follow` gives (the teacher's policy
    over a segment, at ``temperature``), with its LSTM, previous action and previous reward following
    the learner's executed actions. ``learner_tilt_input``: whether the learner's segments keep the
    tilt input (its network reads it); a teacher that reads the tilt needs it."""

    def __init__(
        self,
        source: str | Path,
        task: str,
        action_type: str,
        *,
        learner_tilt_input: bool,
        batch: int,
        temperature: float = 1.0,
    ):
        owner = "PPOFinetuneSettings.kl_teacher"
        net, run = load_labyrinth_teacher(source, task, action_type, owner)
        if run.network.obs != "state":
            raise ValueError(
                f"{owner} {source} observes {run.network.obs!r}: a kickstarting teacher reads the state "
                f"the envs record, so it must be a run on obs 'state' (with or without surroundings)"
            )
        if run.network.tilt_input and not learner_tilt_input:
            raise ValueError(
                f"{owner} {source} reads the tilt input, which the learner's rollouts keep only when its "
                f"own network reads it: train the learner with tilt_input true"
            )
        self.tilt_input = run.network.tilt_input
        board = puzzle(task).spec
        assert isinstance(board, LabyrinthSpec)  # load_labyrinth_teacher refused the maze
        self.surroundings = Surroundings(board) if run.network.surroundings else None
        self.teacher = Teacher(net, batch, temperature)

    def observations(self, privileged: torch.Tensor) -> torch.Tensor:
        """The teacher's observations (…, 17 or 17 + surroundings) of recorded state values (…, 17)."""
        if self.surroundings is None:
            return privileged
        around = torch.from_numpy(self.surroundings.of(privileged[..., :2].numpy()))
        return torch.cat([privileged, around], dim=-1)

    def follow(self, segment: Segment) -> torch.Tensor:
        """The teacher's policy over the segment's T acting steps (see
        :meth:`~bimgame.learn.finetune.Teacher.follow`), read from ``segment.privileged``."""
        if segment.privileged is None:
            raise ValueError(
                "a state teacher reads the simulator's state the envs record (Segment.privileged); "
                "collect with privileged=True"
            )
        tilt = segment.tilt if self.tilt_input else None
        seen = segment.replace(obs=self.observations(segment.privileged), tilt=tilt)
        return self.teacher.follow(seen)
