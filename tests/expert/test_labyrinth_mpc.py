"""Tests of the labyrinth's MPC expert (bimgame.expert.labyrinth_mpc): the score ranks a sequence
into a hole below one that stays clear, sampling and actions in the env's spaces, the expert
outprogresses a random policy on the easy board within 150 steps, and bad settings name the field.
Small K, H and step budgets keep the file within about 20 s on a loaded machine."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.envs.labyrinth_env import LabyrinthEnv
from bimgame.expert.labyrinth_mpc import LabyrinthMPC, LabyrinthMPCConfig, run_labyrinth_expert_episode
from bimgame.sim.labyrinth import LabyrinthSpec


def _near_hole(spec: LabyrinthSpec) -> tuple[np.ndarray, np.ndarray, int]:
    """A point on the path 12–20 mm from a hole's centre (marble clear of walls), that hole and the
    point's segment."""
    path = spec.path
    for s in np.arange(0.0, path.length, 0.002):
        k = min(int(np.searchsorted(path.cumulative, s, side="right")) - 1, path.n_segments - 1)
        p = path.starts[k] + (s - path.cumulative[k]) / path.lengths[k] * path.vectors[k]
        for hole in np.asarray(spec.holes):
            if 0.012 < np.linalg.norm(p - hole) < 0.020 and spec.clearance(p) > spec.marble_radius + 0.001:
                return p, hole, k
    raise AssertionError("no path point near a hole")


def test_score_ranks_a_sequence_into_a_hole_below_one_that_stays_clear():
    spec = LabyrinthSpec.layout("easy")
    config = LabyrinthMPCConfig(n_samples=2, horizon=40)
    expert = LabyrinthMPC(spec, config, rng=np.random.default_rng(0))
    xy, hole, segment = _near_hole(spec)
    expert.sim.reset(xy)
    state = expert.sim.get_state()
    direction = (hole - xy) / np.linalg.norm(hole - xy)
    into = np.tile([-direction[1], direction[0]], (40, 1))  # tilt so that gravity pulls towards the hole
    still = np.zeros((40, 2))
    states = expert.sim.rollout(state, expert.tilt_deltas(np.stack([into, still])))
    positions, _ = expert.sim.layout.board_frame(states)
    assert spec.over_hole(positions[0, :, 0, :2]).any()  # constructed right: one falls in
    assert not spec.over_hole(positions[1, :, 0, :2]).any()  # the other does not
    progress = float(spec.path.project(xy, np.array(segment))[0])
    scores = expert.score(states, segment, progress)
    assert scores[0] < scores[1] - config.hole_penalty / 2


@pytest.mark.parametrize(
    ("action_type", "sampling"),
    [
        ("continuous", "hold"),
        ("continuous", "uniform"),
        ("continuous", "mppi"),
        ("discrete", "hold"),
        ("discrete", "uniform"),
    ],
)
def test_actions_are_in_the_envs_action_space(action_type, sampling):
    env = LabyrinthEnv("easy", action_type=action_type)
    config = LabyrinthMPCConfig(n_samples=4, horizon=6, hold_min=2, hold_max=3, sampling=sampling)
    expert = LabyrinthMPC.for_env(env, config, rng=np.random.default_rng(1))
    sequences = expert.sample_sequences()
    assert sequences.shape[:2] == (4, 6)
    _, info = env.reset(seed=0)
    for _ in range(3):
        action = expert.act(env.unwrapped.sim.get_state(), info["segment"])
        assert env.action_space.contains(action)
        _, _, _, _, info = env.step(action)
    assert expert.act(env.unwrapped.sim.get_state()) in env.action_space  # the segment followed by the expert


def test_hold_sampling_uses_the_rate_levels_in_runs():
    expert = LabyrinthMPC(
        LabyrinthSpec.layout("easy"),
        LabyrinthMPCConfig(n_samples=50, horizon=12, hold_min=4, hold_max=4, rate_levels=3),
        rng=np.random.default_rng(2),
    )
    sequences = expert.sample_sequences()
    assert set(np.unique(sequences)) <= {-1.0, 0.0, 1.0}
    np.testing.assert_array_equal(sequences[:, 0], sequences[:, 3])  # one run of 4 steps
    assert np.any(sequences[:, 3] != sequences[:, 4])


def test_same_seed_same_actions():
    env = LabyrinthEnv("easy")
    config = LabyrinthMPCConfig(n_samples=6, horizon=8)
    state = (env.reset(seed=3), env.unwrapped.sim.get_state())[1]
    actions = [LabyrinthMPC.for_env(env, config, rng=np.random.default_rng(4)).act(state, 0) for _ in range(2)]
    np.testing.assert_array_equal(actions[0], actions[1])


@pytest.mark.parametrize("sampling", ["hold", "mppi"])
def test_expert_outprogresses_a_random_policy_on_the_easy_board(sampling):
    """100 steps (1.8 s) each from the same start: the expert (K=8, H=30) gets well along the path;
    uniformly random tilt rates barely leave the start, or fall. (MPPI with H=20 overshot the first
    corner off the path in 2 of 3 seeds: its averaged plan brakes later than the best sequence.)"""
    env = LabyrinthEnv("easy")
    config = LabyrinthMPCConfig(n_samples=8, horizon=30, sampling=sampling)
    expert = LabyrinthMPC.for_env(env, config, rng=np.random.default_rng(0))
    result = run_labyrinth_expert_episode(env, expert, seed=0, max_steps=100)
    assert result["failure"] in (None, "time") and result["steps"] == 100
    rng = np.random.default_rng(0)
    _, info = env.reset(seed=0)
    start = info["progress"]
    for _ in range(100):
        _, _, terminated, _, info = env.step(rng.uniform(-1.0, 1.0, 2).astype(np.float32))
        if terminated:
            break
    random_progress = info["progress"] - start
    assert result["progress"] - start > random_progress + 0.15, (result, random_progress)


@pytest.mark.parametrize(
    ("field", "value", "allowed"),
    [
        ("n_samples", 0, "positive integer"),
        ("horizon", 2.5, "positive integer"),
        ("sampling", "gauss", "hold, uniform, mppi"),
        ("hold_max", 1, "hold_min"),
        ("rate_levels", 1, ">= 2"),
        ("keep_best", "yes", "True or False"),
        ("hole_penalty", -1.0, ">= 0"),
        ("hole_margin", math.nan, ">= 0"),
        ("off_path_penalty", math.inf, ">= 0"),
        ("path_weight", -0.5, ">= 0"),
        ("nthread", 0, "positive integer"),
        ("n_plans", 0, "positive integer"),
        ("noise_std", 0.0, "> 0"),
        ("temperature", math.inf, "> 0"),
        ("cold_iterations", 0, "positive integer"),
    ],
)
def test_bad_settings_raise_value_error_naming_the_field(field, value, allowed):
    with pytest.raises(ValueError, match=rf"LabyrinthMPCConfig\.{field}.*{allowed}"):
        LabyrinthMPCConfig(**{field: value})


def test_mppi_needs_continuous_actions():
    with pytest.raises(ValueError, match=r"'mppi'.*continuous actions.*hold, uniform"):
        LabyrinthMPC(
            LabyrinthSpec.layout("easy"),
            LabyrinthMPCConfig(sampling="mppi"),
            rng=np.random.default_rng(0),
            action_type="discrete",
        )


def test_more_sequences_than_one_rollout_holds_are_refused():
    with pytest.raises(ValueError, match=r"n_samples × n_plans must be at most 65,536.*got 4096 × 17"):
        LabyrinthMPCConfig(n_samples=4096, n_plans=17)


def _labels(
    n_plans: int, action_type: str = "continuous", repeats: int = 16, sampling: str = "hold"
) -> tuple[np.ndarray, list[dict]]:
    """``repeats`` first decisions of fresh experts (seeds 0..) with P = ``n_plans`` searches of K = 16
    from one state on the hard layout's path, and what each planner saw."""
    env = LabyrinthEnv("hard", action_type=action_type)
    _, info = env.reset(seed=0)
    for _ in range(40):  # the marble rolling, the board tilted
        _, _, _, _, info = env.step(np.array([0.5, -0.5], dtype=np.float32) if action_type == "continuous" else 1)
    state = env.unwrapped.sim.get_state()
    config = LabyrinthMPCConfig(n_samples=16, n_plans=n_plans, horizon=20, sampling=sampling)
    labels, seen = [], []
    for seed in range(repeats):
        action, planned = LabyrinthMPC.for_env(env, config, rng=np.random.default_rng(seed)).plan(state, info["segment"])
        labels.append(np.asarray(action, dtype=np.float64))
        seen.append(planned)
    return np.stack(labels), seen


def test_the_mean_of_several_plans_is_a_less_noisy_label():
    one, _ = _labels(1)
    four, seen = _labels(4)
    assert seen[0]["first_actions"].shape == (4, 2) and seen[0]["scores"].shape == (64,)
    for label, planned in zip(four, seen, strict=True):  # the action is the searches' mean
        np.testing.assert_allclose(label, planned["first_actions"].mean(axis=0), atol=1e-6)
    # Four independent searches: the spread of the label over seeds about halves (1/√4).
    assert four.std(axis=0).mean() < 0.75 * one.std(axis=0).mean()


def test_an_mppi_label_is_less_noisy_than_one_searchs():
    """The score-weighted mean of K sequences moves less between fresh experts than the first action
    of the best one (measured from this state: spread 0.35 against 0.67)."""
    hold, _ = _labels(1)
    mppi, seen = _labels(1, sampling="mppi")
    for label, planned in zip(mppi, seen, strict=True):  # the action is the plan's first
        np.testing.assert_allclose(label, planned["first_actions"].mean(axis=0), atol=1e-6)
    assert mppi.std(axis=0).mean() < 0.75 * hold.std(axis=0).mean()


def _recording_expert(config: LabyrinthMPCConfig, seed: int) -> tuple[LabyrinthMPC, np.ndarray, list[np.ndarray]]:
    """An expert on the easy board, its start state, and the list its rollouts' tilt changes are
    appended to, one (K·P, H, 2) array per ``mujoco.rollout`` call."""
    spec = LabyrinthSpec.layout("easy")
    expert = LabyrinthMPC(spec, config, rng=np.random.default_rng(seed))
    expert.sim.reset(spec.start)
    rolled: list[np.ndarray] = []
    original = expert.sim.rollout
    expert.sim.rollout = lambda s, deltas, **kw: rolled.append(deltas) or original(s, deltas, **kw)
    return expert, expert.sim.get_state(), rolled


def test_mppi_remembers_its_plan_shifted_by_one_step():
    config = LabyrinthMPCConfig(n_samples=4, horizon=6, hold_min=2, hold_max=3, sampling="mppi", cold_iterations=2)
    expert, state, rolled = _recording_expert(config, 5)
    _, first = expert.plan(state, 0)
    assert len(rolled) == 2  # no plan to remember: refined cold_iterations times
    expert.plan(state, 0)
    assert len(rolled) == 3  # then once a decision
    # The second decision's first candidate is the first decision's plan without its applied step.
    np.testing.assert_allclose(rolled[2][0, :-1], first["sequence"][1:] * expert.tilt_step)
    expert.reset()
    expert.plan(state, 0)
    assert len(rolled) == 5  # a new episode starts cold


def test_each_search_refines_its_own_plan():
    config = LabyrinthMPCConfig(n_samples=3, n_plans=2, horizon=5, hold_min=1, hold_max=2)
    expert, state, rolled = _recording_expert(config, 4)
    _, first = expert.plan(state, 0)
    expert.plan(state, 0)
    bests = np.arange(2) * 3 + first["scores"].reshape(2, 3).argmax(axis=1)  # each search's best row
    np.testing.assert_allclose(first["first_actions"] * expert.tilt_step, rolled[0][bests, 0])
    # The second decision's rows 0 and K are the two searches' best sequences, shifted by one step.
    np.testing.assert_allclose(rolled[1][::3, :-1], rolled[0][bests, 1:])


def test_discrete_plans_take_the_most_frequent_action():
    spec = LabyrinthSpec.layout("easy")
    expert = LabyrinthMPC(spec, LabyrinthMPCConfig(n_plans=5), rng=np.random.default_rng(0), action_type="discrete")
    assert expert._combine(np.array([3, 1, 3, 2, 1]), np.array([0.0, 5.0, 1.0, 0.0, 0.0])) == 1  # tie: best score
    assert expert._combine(np.array([3, 1, 3, 2, 4]), np.array([0.0, 5.0, 1.0, 0.0, 0.0])) == 3
    labels, _ = _labels(4, "discrete", repeats=2)
    assert labels.shape == (2,) and set(labels.tolist()) <= set(range(5))


def test_bad_arguments():
    spec = LabyrinthSpec.layout("easy")
    with pytest.raises(TypeError, match="rng"):
        LabyrinthMPC(spec, rng=0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="action_type"):
        LabyrinthMPC(spec, rng=np.random.default_rng(0), action_type="analog")
    expert = LabyrinthMPC(spec, LabyrinthMPCConfig(n_samples=2, horizon=2), rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="state"):
        expert.act(np.zeros(3))
    expert.sim.reset(spec.start)
    with pytest.raises(ValueError, match="segment"):
        expert.act(expert.sim.get_state(), segment=10_000)


class _StillModel:
    """A model in which the marble never moves: the planner must ask it, not the simulator."""

    state_size = 3

    def __init__(self):
        self.calls = 0

    def rollout(self, state, controls, nthread=1):
        self.calls += 1
        return np.broadcast_to(state, (*controls.shape[:2], 3)).copy()

    def marble_xy_of(self, states):
        return np.asarray(states)[..., :2]

    def close(self):
        pass


def test_the_planner_plans_through_any_model_of_the_protocol():
    spec = LabyrinthSpec.layout("easy")
    model = _StillModel()
    expert = LabyrinthMPC(spec, LabyrinthMPCConfig(n_samples=4, horizon=5), rng=np.random.default_rng(0), model=model)
    action, seen = expert.plan(np.array([*spec.start, 0.0]), segment=0)
    assert model.calls == 1 and expert.sim is model
    assert np.all(seen["scores"] == seen["scores"][0])  # a marble that never moves scores alike everywhere
    with pytest.raises(ValueError, match=r"state must have shape \(3,\)"):
        expert.act(np.zeros(8))
    with pytest.raises(TypeError, match="PlanningModel"):
        LabyrinthMPC(spec, rng=np.random.default_rng(0), model=object())  # type: ignore[arg-type]
