"""The game of ``bimgame play`` without a browser: keys to actions, held keys, phases, agent and human
control, and the websocket messages (parsed, applied, or answered with an error)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bimgame.envs.env import BallInMazeEnv
from bimgame.play.agent import AgentPlayer
from bimgame.play.controls import KEY_ACTIONS, HeldKeys
from bimgame.play.protocol import apply_message, parse_message
from bimgame.play.session import PlaySession


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
    assert session.task.value == "STG1"  # the agent's task by default
    assert session.controller == "agent"
    # A second copy of the agent, shown the same steps, predicts the actions the session executes.
    twin = AgentPlayer(tiny_agent_run, session.env.maze, session.env.sim.layout, greedy=True)
    twin.start_episode()

    def twin_step():
        state = session.env.sim.get_state()
        return twin.act(session._obs, state, session._channel, session.env.sim.tilt)

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
    assert session.task.value == "STG2" and session.agent.obs_mode == "pixels"
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
