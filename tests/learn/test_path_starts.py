"""Tests of the labyrinth's start curriculum (bimgame.learn.path_starts): its starts are at rest on
the printed path, clear of walls, holes and the goal, within the stage's distance of the goal; the
stages move with success; it is seeded; vector envs start from its states; the learners' settings
and PPO use it."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from bimgame.envs.labyrinth_vector import LabyrinthVectorEnv
from bimgame.expert.labyrinth_datasets import load_labyrinth_demonstrations
from bimgame.learn.curricula import start_curriculum
from bimgame.learn.learner_settings import CurriculumSettings
from bimgame.learn.path_starts import TRUE_START, DemoPathStarts, PathStartCurriculum
from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_physics import LabyrinthSim


@pytest.fixture(scope="module")
def easy() -> PathStartCurriculum:
    return PathStartCurriculum(LabyrinthSpec.layout("easy"), true_share=0.0, window=4, threshold=0.75)


@pytest.mark.parametrize("layout", ["easy", "medium", "hard"])
def test_starts_are_at_rest_on_the_path_clear_of_walls_holes_and_goal(layout):
    curriculum = PathStartCurriculum(LabyrinthSpec.layout(layout))
    spec = curriculum.spec
    sim = LabyrinthSim(spec)
    length = spec.path.length
    assert len(curriculum.arcs) > 0.8 * length / 0.005  # most of the path is usable
    assert np.all(np.diff(curriculum.arcs) > 0)
    for state, arc in zip(curriculum.states, curriculum.arcs, strict=True):
        sim.set_state(state)
        x, y, vx, vy = sim.layout.board_frame_one(sim.data.qpos, sim.data.qvel)[0]
        assert (vx, vy) == (0.0, 0.0)
        assert float(spec.clearance([x, y])) >= spec.marble_radius - 1e-9
        holes = np.asarray(spec.holes)
        assert np.linalg.norm(holes - [x, y], axis=1).min() >= spec.hole_radius + spec.marble_radius
        assert math.dist((x, y), spec.waypoints[-1]) > spec.goal_radius
        assert 0 <= length - arc <= length
    sim.close()


def test_stage_starts_lie_within_its_distance_of_the_goal_and_move_back_with_success(easy):
    curriculum = PathStartCurriculum(LabyrinthSpec.layout("easy"), true_share=0.0, window=4, threshold=0.75)
    rng = np.random.default_rng(0)
    by_state = {state.tobytes(): back for state, back in zip(curriculum.states, curriculum.back_of, strict=True)}
    backs = []
    for _ in range(200):
        state, tag = curriculum(0, rng)
        assert tag == 0 and state is not None
        backs.append(by_state[state.tobytes()])
    assert max(backs) <= 0.10 and min(backs) < 0.03 and len(set(backs)) > 10  # uniform over the last 10 cm
    for _ in range(4):
        curriculum.record(0, True)
    assert curriculum.stage == 1 and curriculum.status()["curriculum_start_distance"] == pytest.approx(0.15)
    farther = [by_state[curriculum(0, rng)[0].tobytes()] for _ in range(200)]
    assert 0.10 < max(farther) <= 0.15
    while not curriculum.finished:
        for _ in range(4):
            curriculum.record(curriculum.stage, True)
    assert curriculum(0, rng) == (None, TRUE_START) and curriculum.status()["true_start_share"] == 1.0


def test_true_share_and_the_same_seed_gives_the_same_starts():
    curriculum = PathStartCurriculum(LabyrinthSpec.layout("medium"), true_share=0.3)
    draws = [curriculum(0, np.random.default_rng(5)) for _ in range(2)]
    assert draws[0][1] == draws[1][1]
    rng_a, rng_b = np.random.default_rng(9), np.random.default_rng(9)
    tags = []
    for _ in range(300):
        (a, tag_a), (b, tag_b) = curriculum(0, rng_a), curriculum(0, rng_b)
        assert tag_a == tag_b and (a is None) == (b is None) and (a is None or np.array_equal(a, b))
        tags.append(tag_a)
    assert 0.2 < tags.count(TRUE_START) / len(tags) < 0.4


def test_settings_are_refused_by_name():
    spec = LabyrinthSpec.layout("easy")
    for name, value, allowed in [("first_back", 0.0, r"\(0, "), ("growth", 1.0, r"\(1, 100\]"),
                                 ("threshold", 1.5, r"\(0, 1\]"), ("true_share", -0.1, r"\[0, 1\]"),
                                 ("spacing", math.nan, r"\(0, ")]:
        with pytest.raises(ValueError, match=rf"PathStartCurriculum\.{name} must be a number in {allowed}"):
            PathStartCurriculum(spec, **{name: value})
    with pytest.raises(ValueError, match=r"PathStartCurriculum\.window must be an integer >= 1, got 0"):
        PathStartCurriculum(spec, window=0)
    with pytest.raises(TypeError, match="spec must be a LabyrinthSpec"):
        PathStartCurriculum("easy")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"record: tag must be an integer"):
        PathStartCurriculum(spec).record("0", True)  # type: ignore[arg-type]


def test_vector_envs_start_from_its_states_and_keep_its_tags(easy):
    env = LabyrinthVectorEnv(3, "easy", obs_mode="state", start_sampler=easy)
    obs, _ = env.reset(seed=1)
    progress = obs[:, 6] * env.path.length
    assert np.all(env.start_tags == easy.stage)
    assert np.all(env.path.length - progress <= easy.stages.back + 1e-6)  # the tracker places them near the goal
    # A marble started 10 cm before the goal and held still on a level board earns no progress yet.
    _, reward, terminated, truncated, _ = env.step(np.zeros((3, 2), dtype=np.float32))
    assert not terminated.any() and np.allclose(reward, 0.0, atol=1e-3)
    env.close()


def test_a_start_samplers_wrong_returns_are_refused_by_name():
    env = LabyrinthVectorEnv(2, "easy", obs_mode="state", start_sampler=lambda i, rng: (np.zeros(3), 0))
    with pytest.raises(ValueError, match=r"the start_sampler's state for board 0 \(tag 0\): state must be a finite"):
        env.reset(seed=0)
    env = LabyrinthVectorEnv(2, "easy", obs_mode="state", start_sampler=lambda i, rng: "start")
    with pytest.raises(ValueError, match=r"start_sampler must return \(state or None, integer tag\)"):
        env.reset(seed=0)
    with pytest.raises(ValueError, match=r"start_sampler must be None or a callable"):
        LabyrinthVectorEnv(2, "easy", start_sampler=3)  # type: ignore[arg-type]


def test_a_sampler_giving_the_layouts_start_changes_nothing_but_the_tags():
    plain = LabyrinthVectorEnv(3, "hard", obs_mode="state")
    tagged = LabyrinthVectorEnv(3, "hard", obs_mode="state", start_sampler=lambda i, rng: (None, 7))
    a, _ = plain.reset(seed=4)
    b, _ = tagged.reset(seed=4)
    assert np.array_equal(a, b) and np.all(tagged.start_tags == 7) and np.all(plain.start_tags == 0)


def test_learners_build_it_for_the_labyrinths_reverse_curriculum():
    reverse = start_curriculum("LABYRINTH-HARD", CurriculumSettings("reverse", 0.6))
    assert isinstance(reverse, PathStartCurriculum) and reverse.stages.threshold == 0.6
    assert start_curriculum("LABYRINTH-HARD", None) is None
    with pytest.raises(ValueError, match="start_curriculum 'demo' needs expert_data"):
        start_curriculum("LABYRINTH-EASY", CurriculumSettings("demo"))


def test_ppo_trains_with_it_on_the_labyrinth_and_logs_its_stage(tmp_path):
    from bimgame.cli.main import main

    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--task", "LABYRINTH-EASY", "--obs", "state", "--action-type",
                 "continuous", "--start-curriculum", "reverse", "--curriculum-threshold", "0.5", "--steps", "4096",
                 "--n-steps", "64", "--envs-per-worker", "8", "--log-every", "512", "--eval-episodes", "1",
                 "--run-dir", str(run_dir), "--no-progress"]) == 0
    with open(run_dir / "episodes.csv", newline="") as handle:
        episodes = list(csv.DictReader(handle))
    curriculum = [row for row in episodes if row["true_start"] == "False"]
    assert len(curriculum) > len(episodes) / 2  # 90% of the starts are the curriculum's
    with open(run_dir / "updates.csv", newline="") as handle:
        updates = list(csv.DictReader(handle))
    assert updates and all(row["curriculum_stage"] != "" for row in updates)
    assert float(updates[-1]["curriculum_start_distance"]) >= 0.10


# ------------------------------------------------------------------------ demonstration starts
def _moving_demonstration(spec: LabyrinthSpec) -> tuple[np.ndarray, np.ndarray]:
    """A made-up demonstration: the path curriculum's rest states with a velocity of 5 cm/s added,
    and their arc lengths as the progress (the last state, after the last step, never a start)."""
    rest = PathStartCurriculum(spec)
    sim = LabyrinthSim(spec)
    states = []
    for state in rest.states:
        sim.set_state(state)
        sim.data.qvel[2] = 0.05  # the marble's free joint follows the two hinges: a marble in motion
        states.append(sim.get_state())
    moving = sim.layout.board_frame(np.array(states))[1]
    sim.close()
    assert np.all(np.abs(moving[..., 0]) > 0.01)
    return np.array(states), rest.arcs.copy()


def test_demonstration_starts_are_the_experts_states_within_the_stages_distance():
    spec = LabyrinthSpec.layout("easy")
    states, arcs = _moving_demonstration(spec)
    shifted = arcs.copy()
    shifted[::2] += 0.05  # every other state recorded 5 cm ahead of where the progress rule places it
    curriculum = DemoPathStarts(spec, [(states, shifted)], true_share=0.0, window=4, threshold=0.75)
    # The last state (after the last step) and the misplaced ones are no starts.
    assert len(curriculum.states) == len(states[1:-1:2])
    np.testing.assert_array_equal(curriculum.states, states[1:-1:2])
    np.testing.assert_allclose(curriculum.back_of, spec.path.length - arcs[1:-1:2])
    np.testing.assert_allclose(curriculum.path_fractions, arcs[1:-1:2] / spec.path.length)
    rng = np.random.default_rng(0)
    by_state = {s.tobytes(): b for s, b in zip(curriculum.states, curriculum.back_of, strict=True)}
    backs = [by_state[curriculum(0, rng)[0].tobytes()] for _ in range(100)]
    assert max(backs) <= 0.10 and len(set(backs)) > 3
    for _ in range(4):
        curriculum.record(0, True)
    assert curriculum.status()["curriculum_start_distance"] == pytest.approx(0.15)
    env = LabyrinthVectorEnv(2, "easy", obs_mode="state", start_sampler=curriculum)
    env.reset(seed=0)
    assert np.all(env.start_tags == curriculum.stage)
    env.close()


def test_demonstration_starts_refuse_what_they_cannot_use(easy_expert_episode, tmp_path):
    spec = LabyrinthSpec.layout("easy")
    states, arcs = _moving_demonstration(spec)
    with pytest.raises(ValueError, match=r"demonstration 0 must give sim_states \(T\+1, 20\) and progress \(T\+1,\)"):
        DemoPathStarts(spec, [(states[:, :5], arcs)])
    with pytest.raises(ValueError, match="demonstration 0 must give"):
        DemoPathStarts(spec, [(states, arcs[:-1])])
    bad = states.copy()
    bad[3, 0] = np.nan
    with pytest.raises(ValueError, match="demonstration 0 has values that are not finite"):
        DemoPathStarts(spec, [(bad, arcs)])
    with pytest.raises(ValueError, match="gives no start"):
        DemoPathStarts(spec, [])
    with pytest.raises(ValueError, match=r"DemoPathStarts\.threshold must be a number in \(0, 1\]"):
        DemoPathStarts(spec, [(states, arcs)], threshold=0.0)
    with pytest.raises(ValueError, match="holds LABYRINTH-EASY episodes; demonstration starts for LABYRINTH-HARD"):
        DemoPathStarts.from_dataset(easy_expert_episode, "LABYRINTH-HARD")


def _drawn_path_fractions(curriculum: DemoPathStarts, draws: int) -> np.ndarray:
    """How far along the path the demonstration starts of ``draws`` resets lie (true starts left out)."""
    rng = np.random.default_rng(0)
    fractions = []
    for _ in range(draws):
        state, tag = curriculum(0, rng)
        if tag != TRUE_START:
            fractions.append(curriculum.path_fractions[np.flatnonzero((curriculum.states == state).all(axis=1))[0]])
    return np.array(fractions)


def test_uniform_demonstration_starts_cover_the_whole_path_from_the_first_episode(easy_expert_episode):
    """``demo-uniform``: from the first reset the starts spread over the whole demonstration, about
    evenly; ``demo`` starts within its first 10 cm of path before the goal."""
    uniform = start_curriculum("LABYRINTH-EASY", CurriculumSettings("demo-uniform"), easy_expert_episode)
    demo = start_curriculum("LABYRINTH-EASY", CurriculumSettings("demo"), easy_expert_episode)
    spread = _drawn_path_fractions(uniform, 400)
    assert 300 < len(spread) < 400  # ≈ 10% true starts
    assert spread.min() < 0.1 and spread.max() > 0.9
    assert 0.35 < np.mean(spread < 0.5) < 0.65  # the marble's slow and fast parts are not far from even
    near_goal = _drawn_path_fractions(demo, 100)
    length = LabyrinthSpec.layout("easy").path.length
    assert near_goal.min() >= 1 - 0.10 / length - 1e-9
    reach = uniform.status()["curriculum_start_distance"]  # the farthest state: the demonstration's first
    assert reach == uniform.back_of.max() and reach > 0.99 * length


def test_learners_start_from_the_experts_dataset_on_the_labyrinth(easy_expert_episode, tmp_path):
    task, demonstrations = load_labyrinth_demonstrations(easy_expert_episode)
    assert task == "LABYRINTH-EASY" and len(demonstrations) == 1
    sim_states, progress = demonstrations[0]
    assert progress[0] < 0.01 and progress[-1] == pytest.approx(LabyrinthSpec.layout("easy").path.length, abs=0.05)
    curriculum = start_curriculum("LABYRINTH-EASY", CurriculumSettings("demo", 0.6), easy_expert_episode)
    assert isinstance(curriculum, DemoPathStarts) and curriculum.stages.threshold == 0.6
    assert len(curriculum.states) > 0.9 * (len(sim_states) - 1)  # nearly every state before a step
    from bimgame.cli.main import main

    run_dir = tmp_path / "run"
    assert main(["train", "--algo", "ppo", "--task", "LABYRINTH-EASY", "--obs", "state", "--action-type",
                 "continuous", "--start-curriculum", "demo", "--expert-data", str(easy_expert_episode),
                 "--steps", "2048", "--n-steps", "64", "--envs-per-worker", "8", "--log-every", "512", "--eval-episodes", "1",
                 "--no-progress", "--run-dir", str(run_dir)]) == 0
    with open(run_dir / "updates.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert rows and all(float(row["curriculum_start_distance"]) >= 0.10 for row in rows)
    with open(run_dir / "episodes.csv", newline="") as handle:
        episodes = list(csv.DictReader(handle))
    assert any(row["true_start"] == "False" for row in episodes)  # episodes started from the demonstration
