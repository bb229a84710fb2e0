"""The start curriculum a learner's settings ask for, on either puzzle, and the columns its status is
logged under: one place for A3C's workers and PPO's ranks.

- ``demo``: the expert's states, on the maze by steps of its episodes
  (:class:`~bimgame.learn.starts.DemoStartCurriculum`), on the labyrinth by metres of its path
  (:class:`~bimgame.learn.path_starts.DemoPathStarts`).
- ``demo-uniform``: the same starts, every state of the expert's episodes from the first episode on
  (one stage reaching back to the farthest state; reference state initialisation, Peng et al. 2018):
  every passage is practised from the start of training, not only those near the goal.
- ``reverse``: without expert data, grown back from the goal — on the maze by random walks
  (:class:`~bimgame.learn.starts.ReverseCurriculum`), on the labyrinth along its printed path
  (:class:`~bimgame.learn.path_starts.PathStartCurriculum`).
"""

from __future__ import annotations

from pathlib import Path

from bimgame.envs.puzzles import puzzle
from bimgame.learn.learner_settings import CurriculumSettings
from bimgame.learn.path_starts import DemoPathStarts, PathStartCurriculum
from bimgame.learn.starts import DemoStartCurriculum, ReverseCurriculum
from bimgame.sim.labyrinth import LabyrinthSpec

__all__ = ["StartCurriculumSampler", "CURRICULUM_COLUMNS", "CURRICULUM_SCALARS", "start_curriculum"]

#: What :func:`start_curriculum` returns: a start sampler with ``record`` and ``status``.
StartCurriculumSampler = DemoStartCurriculum | ReverseCurriculum | PathStartCurriculum | DemoPathStarts
#: Every key a curriculum's ``status()`` may report: the learners' ``updates`` log columns.
CURRICULUM_COLUMNS = (
    "curriculum_stage",
    "curriculum_steps_back",
    "curriculum_pool",
    "curriculum_good",
    "curriculum_mastered",
    "curriculum_start_distance",
    "curriculum_window_success",
    "true_start_share",
)
#: Of those, the ones that also go to TensorBoard.
CURRICULUM_SCALARS = ("curriculum_stage", "curriculum_steps_back", "curriculum_start_distance")


def start_curriculum(
    task: str, curriculum: CurriculumSettings | None, expert_data: str | Path | None = None
) -> StartCurriculumSampler | None:
    """The start curriculum of a process's training episodes on ``task`` (None: the task's own starts).
    The settings are checked already (:func:`~bimgame.learn.learner_settings.check_start_curriculum`);
    the maze's curricula are for MERL's maze."""
    if curriculum is None:
        return None
    threshold = curriculum.curriculum_threshold
    spec = puzzle(task).spec
    labyrinth = isinstance(spec, LabyrinthSpec)
    if curriculum.reads_demonstrations:
        if expert_data is None:
            raise ValueError(
                f"start_curriculum {curriculum.start_curriculum!r} needs expert_data (an expert dataset directory)"
            )
        demo = DemoPathStarts if labyrinth else DemoStartCurriculum
        every_state = {"first_back": None} if curriculum.start_curriculum == "demo-uniform" else {}
        return demo.from_dataset(expert_data, task, threshold=threshold, **every_state)
    if isinstance(spec, LabyrinthSpec):
        return PathStartCurriculum(spec, threshold=threshold)
    # A pool of 32 starts (not the class's 100): each start is tried 3 times before the pool grows,
    # and a failed STG3 episode lasts 750 steps, so 100 starts held one pool for ≈ 230k steps.
    return ReverseCurriculum(task, high=threshold, pool_size=32)
