"""The game of ``bimgame play`` without a browser: keys to actions, held keys, phases, agent and human
control, and the websocket messages (parsed, applied, or answered with an error)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bimgame.cli.main import main
from bimgame.envs.env import BallInMazeEnv
from bimgame.play.agent import AgentPlayer
from bimgame.play.boards import LabyrinthBoard
from bimgame.play.controls import KEY_ACTIONS, HeldKeys, action_name
from bimgame.play.protocol import apply_message, parse_message
from bimgame.play.server import PlayServer
from bimgame.play.session import PlaySession, refuse_unsupported


# ------------------------------------------------------------------------------ keys → actions
@pytest.mark.parametrize("key, direction", [("up", (0, 1)), ("down", (0, -1)), ("left", (-1, 0)), ("right", (1, 0))])
def test_each_key_rolls_the_marble_that_way_on_the_screen(key, direction):
    """The screen shows +y up and +x right (MazeRenderer): holding "up" must roll the marble towards
    +y, and so on. The marble starts where that direction runs along its channel."""
    env = BallInMazeEnv("STG1", obs_mode="state")
    obs, _ = env.reset(seed=0)
    radius = math.hypot(obs[0], obs[1])  # every start is on the outermost channel's centre circle
    start = [[radius, 0.0]] if direction[0] == 0 else [[0.0, radius]]
    obs, _ = env.reset(options={"marble_xy": start})
    for _ in range(12):
        obs, *_ = env.step(KEY_ACTIONS[key])
    moved = np.asarray(obs[:2], dtype=np.float64) - start[0]
    along = float(moved @ np.asarray(direction))
    across = abs(float(moved @ np.asarray(direction[::-1])))
    env.close()
    assert along > 0.005, f"{key}: the marble moved {moved} (m), not {direction}"
    assert across < 0.5 * along, f"{key}: the marble moved {moved} (m), mostly not {direction}"


def test_the_noop_key_holds_the_board():
    env = BallInMazeEnv("STG1", obs_mode="state")
    before, _ = env.reset(seed=1)
    for _ in range(10):
        after, *_ = env.step(KEY_ACTIONS["noop"])
    env.close()
    assert np.abs(after[:2] - before[:2]).max() < 1e-4
    assert np.abs(after[4:6]).max() < 1e-3  # no tilt (rad), up to the servo settling


def test_held_keys_latest_press_counts_across_clients():
    keys = HeldKeys()
    assert keys.action() == KEY_ACTIONS["noop"]
    assert keys.set("a", ["up"])
    assert keys.action() == KEY_ACTIONS["up"]
    assert keys.set("a", ["up", "left"]) and keys.action() == KEY_ACTIONS["left"]
    assert not keys.set("a", ["up", "left"])  # no new press: the same set again
    assert not keys.set("a", ["up"]) and keys.action() == KEY_ACTIONS["up"]  # left released
    assert keys.set("b", ["right"]) and keys.action() == KEY_ACTIONS["right"]  # another tab pressed later
    keys.drop("b")  # that tab closed: its keys are released
    assert keys.action() == KEY_ACTIONS["up"]
    keys.set("a", [])
    assert keys.action() == KEY_ACTIONS["noop"] and not keys.any()


# ------------------------------------------------------------------------------ the session
def test_episode_waits_for_the_first_key_then_a_held_key_repeats_each_step():
    session = PlaySession("STG1", max_steps=50, seed=0)
    for _ in range(5):
        assert not session.tick()
    assert session.phase == "ready" and session.steps == 0
    session.set_keys("tab", ["right"])
    actions = []
    for _ in range(6):
        assert session.tick()
        actions.append(session.last_action)
    assert session.phase == "running" and session.steps == 6
    assert actions == [KEY_ACTIONS["right"]] * 6
    tilt = session.env.sim.tilt.copy()
    session.set_keys("tab", [])  # released: the no-op, the board keeps its tilt
    session.tick()
    assert session.last_action == KEY_ACTIONS["noop"]
    np.testing.assert_allclose(session.env.sim.tilt, tilt, atol=1e-3)
    session.drop_client("tab")
    session.close()


def test_time_limit_ends_the_episode_then_the_next_begins_ready():
    session = PlaySession("STG1", max_steps=5, seed=0, over_ticks=3)
    first_start = session.marble_xy
    session.set_keys("tab", ["noop"])
    for _ in range(5):
        session.tick()
    assert session.phase == "over" and session.steps == 5 and not session.success
    assert session.history[-1]["reason"] == "time limit"
    for _ in range(3):
        session.tick()
    assert session.phase == "ready" and session.episode == 1 and session.steps == 0
    assert session.marble_xy != first_start  # a new start
    session.tick()
    assert session.phase == "ready"  # the key held through the pause does not start it: a new press does
    session.set_keys("tab", ["noop", "up"])
    session.tick()
    assert session.phase == "running"
    session.reset()  # R mid-episode: the next episode at once
    assert session.phase == "ready" and session.episode == 2 and session.history[-1]["reason"] == "reset"
    session.close()


def test_agent_plays_and_control_switches_mid_episode(tiny_agent_run):
    session = PlaySession(max_steps=200, seed=0, agent=tiny_agent_run)
    assert session.task == "STG1"  # the agent's task by default
    assert session.controller == "agent"
    # A second copy of the agent, shown the same steps, predicts the actions the session executes.
    twin = AgentPlayer(tiny_agent_run, session.env.maze, session.env.sim.layout, greedy=True)
    twin.start_episode()

    def twin_step():
        return twin.act(session.board.moment())

    for _ in range(5):  # the agent does not wait for a key
        predicted = twin_step()
        assert session.tick()
        assert session.last_action == predicted
        twin.observe(predicted, 0.0, False)
    session.set_controller("human")
    session.set_keys("tab", ["left"])
    for _ in range(4):
        twin_step()
        session.tick()
        assert session.last_action == KEY_ACTIONS["left"]
        twin.observe(KEY_ACTIONS["left"], 0.0, False)  # the agent saw the person's actions
    session.set_controller("agent")
    for _ in range(3):
        predicted = twin_step()
        session.tick()
        assert session.last_action == predicted
        twin.observe(predicted, 0.0, False)
    assert session.steps == 12
    session.set_greedy(False)
    assert session.snapshot()["agent"]["greedy"] is False
    json.dumps(session.snapshot())  # the page's state is JSON
    session.close()


def test_a_pixel_agent_sees_the_pixels_a_pixel_dataset_would_hold(tiny_pixel_agent_run):
    session = PlaySession(agent=tiny_pixel_agent_run, max_steps=20)
    assert session.task == "STG2" and session.agent.obs_mode == "pixels"
    seen = []
    original = session.agent._actor.act
    session.agent._actor.act = lambda obs, tilt: (seen.append(np.asarray(obs).copy()), original(obs, tilt))[1]
    for _ in range(3):
        assert session.tick() and 0 <= session.last_action <= 4
    env = BallInMazeEnv("STG2", obs_mode="pixels")  # the env's own pixel observation of the same state
    expected, _ = env.reset(options={"sim_state": session.env.sim.get_state()})
    env.close()
    session.tick()
    assert seen[-1].shape == (1, 1, 84, 84) and seen[-1].dtype == np.uint8
    np.testing.assert_array_equal(seen[-1][0], expected)
    session.close()


def test_no_agent_refuses_agent_control():
    session = PlaySession("STG1", max_steps=10)
    with pytest.raises(ValueError, match="--agent"):
        session.set_controller("agent")
    with pytest.raises(ValueError, match="--agent"):
        session.set_greedy(True)
    assert session.controller == "human"
    session.close()


# ------------------------------------------------------------------------------ messages
MALFORMED = [
    ("not json", "not JSON"),
    ("[1, 2]", "JSON object"),
    ('"up"', "JSON object"),
    ("{}", "unknown message type"),
    ('{"type": "jump"}', "unknown message type"),
    ('{"type": "keys"}', "missing fields"),
    ('{"type": "keys", "held": "up"}', "list"),
    ('{"type": "keys", "held": ["jump"]}', "unknown keys"),
    ('{"type": "keys", "held": [7]}', "unknown keys"),
    ('{"type": "keys", "held": [["up"]]}', "unknown keys"),
    ('{"type": "keys", "held": ["up"], "action": 2}', "unknown fields"),
    ('{"type": "control", "who": "robot"}', "'who' must be"),
    ('{"type": "control", "who": "agent"}', "no agent"),
    ('{"type": "greedy", "value": 1}', "true or false"),
    ('{"type": "greedy", "value": true}', "no agent"),
    ('{"type": "keys", "held": ["up"]}' + " " * 5000, "too long"),
    (b"\x00\x01binary", "binary"),
]


@pytest.mark.parametrize("text, reason", MALFORMED, ids=[str(m[0])[:30] for m in MALFORMED])
def test_malformed_messages_are_answered_and_change_nothing(text, reason):
    session = PlaySession("STG1", max_steps=10)
    reply = apply_message(session, "tab", text)
    assert reply is not None and reply["type"] == "error" and reason in reply["message"], reply
    json.dumps(reply)
    assert session.phase == "ready" and session.steps == 0 and not session.keys.any()
    assert session.controller == "human"
    # and the session still takes valid messages
    assert apply_message(session, "tab", '{"type": "keys", "held": ["up"]}') is None
    session.tick()
    assert session.steps == 1 and session.last_action == KEY_ACTIONS["up"]
    assert apply_message(session, "tab", '{"type": "reset"}') is None
    assert session.steps == 0
    session.close()


def test_valid_messages_parse():
    assert parse_message('{"type": "keys", "held": []}') == {"type": "keys", "held": []}
    assert parse_message('{"type": "control", "who": "human"}')["who"] == "human"
    assert parse_message('{"type": "greedy", "value": false}')["value"] is False


# ------------------------------------------------------------------------------ the labyrinth
def _marble_pixel(frame: np.ndarray) -> np.ndarray:
    """(row, col) of the labyrinth render's blue marble (the only blue there)."""
    rows, cols = np.nonzero(np.abs(frame.astype(int) - [40, 90, 230]).sum(-1) < 60)
    return np.array([rows.mean(), cols.mean()])


@pytest.mark.parametrize("key, direction", [("up", (0, 1)), ("down", (0, -1)), ("left", (-1, 0)), ("right", (1, 0))])
def test_each_key_rolls_the_labyrinths_marble_that_way_on_the_screen(key, direction):
    """The labyrinth's discrete actions mean what the maze's do: from an open spot of the easy board
    (24 mm from any wall or hole), holding a key tilts the board and rolls the marble that way in
    the board frame and in the rendered frame (rows grow downwards)."""
    board = LabyrinthBoard("LABYRINTH-EASY", render_size=240)
    spot = (0.11, -0.09)
    board.obs, board.info = board.env.reset(options={"marble_xy": spot})
    before = _marble_pixel(board.frame())
    for _ in range(14):
        result = board.step(board.key_action(KEY_ACTIONS[key]))
    moved = np.subtract(board.marble_xy, spot)
    pixels = _marble_pixel(board.frame()) - before
    tilt = np.degrees(board.tilt)
    board.close()
    assert not result.terminated
    assert float(moved @ np.asarray(direction)) > 0.005, f"{key}: the marble moved {moved} (m), not {direction}"
    assert abs(float(moved @ np.asarray(direction[::-1]))) < 1e-3, moved
    on_screen = np.array([pixels[1], -pixels[0]])  # (right, up) of the marble's (row, col) shift
    assert float(on_screen @ np.asarray(direction)) > 4, f"{key}: moved {pixels} (row, col) px on the screen"
    # up/down tilt about x (up: -x), left/right about y (right: +y), 14 steps of 30°/s at 55 Hz = 7.6°
    expected = {"up": (-7.6, 0), "down": (7.6, 0), "left": (0, -7.6), "right": (0, 7.6)}[key]
    np.testing.assert_allclose(tilt, expected, atol=0.1)


def test_keys_move_a_continuous_labyrinth_exactly_as_a_discrete_one():
    """With a continuous-action agent the session's env is continuous: the person's keys are sent as
    the same tilt changes (DISCRETE_TILTS rows), and the physics is bit for bit the discrete env's."""
    boards = [LabyrinthBoard("LABYRINTH-HARD", action_type=kind) for kind in ("discrete", "continuous")]
    for board in boards:
        board.reset(7)
        for key in ["left"] * 10 + ["down"] * 5 + ["noop"] * 3:
            board.step(board.key_action(KEY_ACTIONS[key]))
    np.testing.assert_array_equal(boards[0].env.sim.get_state(), boards[1].env.sim.get_state())
    assert action_name(boards[1].key_action(KEY_ACTIONS["left"])) == "left"
    for board in boards:
        board.close()


def test_labyrinth_session_renders_steps_at_55_hz_and_ends_in_a_hole_or_at_the_time_limit():
    session = PlaySession("labyrinth-hard", seed=0, max_steps=30, over_ticks=2, render_size=240)
    assert session.task == "LABYRINTH-HARD" and session.tick_hz == 55 and session.env.action_type == "discrete"
    assert session.frame().shape == (240, 240, 3) and session.frame().dtype == np.uint8
    state = session.snapshot()
    assert state["puzzle"] == "labyrinth" and 0 <= state["progress"] < 0.01 and state["phase"] == "ready"
    json.dumps(state)
    session.set_keys("tab", ["noop"])  # the marble stays at its start until the time limit
    while session.phase != "over":
        assert session.tick()
    assert session.steps == 30 and not session.success and session.history[-1]["reason"] == "time limit"
    for _ in range(2):
        session.tick()
    assert session.phase == "ready" and session.episode == 1
    # From this start: left for 20 steps, then down, drops the marble into a hole (48 steps).
    session.max_steps = 3000
    session.set_keys("tab", ["left"])
    for _ in range(20):
        session.tick()
    assert session.snapshot()["progress"] > 0  # rolling along the path
    session.set_keys("tab", ["down"])
    while session.phase == "running":
        session.tick()
    last = session.history[-1]
    assert last["reason"] == "hole" and last["success"] is False and session.steps < 200, last
    assert session.snapshot()["last"]["reason"] == "hole"
    session.close()


def test_the_expert_plays_the_labyrinth_the_same_for_the_same_seed():
    def play(steps: int) -> tuple[PlaySession, list[np.ndarray]]:
        session = PlaySession("LABYRINTH-EASY", agent="expert", seed=3, max_steps=100)
        actions = []
        for _ in range(steps):
            assert session.tick()  # the expert does not wait for a key
            actions.append(session.last_action)
        return session, actions

    session, actions = play(8)
    assert session.controller == "agent" and session.env.action_type == "continuous"
    assert "MPC expert" in session.snapshot()["agent"]["name"] and session.snapshot()["agent"]["greedy"] is None
    assert all(a.shape == (2,) and a.dtype == np.float32 and np.abs(a).max() <= 1 for a in actions)
    with pytest.raises(ValueError, match="expert.*greedy"):
        session.set_greedy(False)
    session.set_controller("human")  # H: the keys take over, as continuous tilt changes
    session.set_keys("tab", ["right"])
    session.tick()
    assert session.snapshot()["action"] == "right"
    twin, twin_actions = play(8)
    np.testing.assert_array_equal(np.array(actions), np.array(twin_actions))
    session.close()
    twin.close()


def test_the_expert_plays_the_maze_too():
    session = PlaySession("STG1", agent="expert", seed=0, max_steps=50)
    for _ in range(3):
        assert session.tick() and session.last_action in range(5)
    session.close()


def test_a_run_that_reads_the_surroundings_plays_with_them(labyrinth_runs):
    session = PlaySession(agent=labyrinth_runs["surroundings", "continuous"], seed=0, max_steps=20)
    assert session.env.surroundings is not None and session.env.observation_space.shape == (33,)
    for _ in range(3):
        assert session.tick() and session.last_action.shape == (2,)
    session.close()


@pytest.mark.parametrize("kind", [("state", "continuous"), ("pixels", "discrete"), ("cyberrunner", "continuous")],
                         ids="-".join)
def test_a_run_trained_on_the_labyrinth_plays_it_with_its_observations_and_actions(labyrinth_runs, kind):
    obs, action_type = kind
    session = PlaySession(agent=labyrinth_runs[kind], seed=0, max_steps=100)
    assert session.task == "LABYRINTH-HARD" and session.controller == "agent"  # the run's task by default
    assert session.env.action_type == action_type
    assert session.env.obs_mode == {"cyberrunner": "cyberrunner_flat"}.get(obs, obs)
    # A second copy of the agent, shown the same steps, predicts the actions the session executes.
    twin = AgentPlayer(labyrinth_runs[kind], session.env.board, task="LABYRINTH-HARD")
    twin.start_episode()
    for step in range(6):
        if step == 3:  # the person takes over for two steps: the agent is told their tilts
            session.set_controller("human")
            session.set_keys("tab", ["up"])
        if step == 5:
            session.set_controller("agent")
        predicted = twin.act(session.board.moment())
        assert session.tick()
        if session.controller == "agent":
            np.testing.assert_array_equal(session.last_action, predicted)
        twin.observe(session.last_action, session.last_reward, False)  # what was executed, and its reward
        if action_type == "continuous":
            assert session.last_action.shape == (2,) and np.abs(session.last_action).max() <= 1
        else:
            assert session.last_action in range(5)
    assert session.snapshot()["agent"]["greedy"] is True
    json.dumps(session.snapshot())
    session.close()


def test_what_play_cannot_do_is_refused_by_name(tiny_agent_run, labyrinth_runs, tmp_path, capsys):
    with pytest.raises(ValueError, match="--record.*maze's tasks only.*FULL.*LABYRINTH-HARD.*--agent expert"):
        refuse_unsupported("LABYRINTH-HARD", recording=True)
    refuse_unsupported("LABYRINTH-HARD", recording=False)
    refuse_unsupported("STG1", recording=True)
    record = tmp_path / "human"
    assert main(["play", "--task", "labyrinth-easy", "--record", str(record)]) == 2
    assert "--record" in capsys.readouterr().err and not record.exists()  # refused before anything is made
    with pytest.raises(ValueError, match="trained on STG1.*LABYRINTH-HARD"):
        PlaySession("LABYRINTH-HARD", agent=tiny_agent_run)
    with pytest.raises(ValueError, match="trained on LABYRINTH-HARD.*FULL"):
        PlaySession("FULL", agent=labyrinth_runs["state", "continuous"])
    with pytest.raises(ValueError, match="unknown task 'MAZE9'.*LABYRINTH-EASY"):
        PlaySession("MAZE9")
    with pytest.raises(ValueError, match="--sampled: the MPC expert"):
        PlaySession("LABYRINTH-EASY", agent="expert", greedy=False)


def test_the_server_ticks_at_the_labyrinths_rate_and_tells_the_page_its_puzzle():
    session = PlaySession("LABYRINTH-MEDIUM", max_steps=10)
    server = PlayServer(session)
    hello = server._hello()
    assert server.hz == 55 and hello["hz"] == 55 and hello["puzzle"] == "labyrinth"
    assert hello["task"] == "LABYRINTH-MEDIUM" and hello["max_steps"] == 10
    server._tick()  # a frame encoded, the state sent (to nobody)
    assert server._frame[:2] == b"\xff\xd8"  # a JPEG
    session.close()
