"""The random mazes a run trains on, as every learner's settings check them (A3C's and PPO's through
:class:`~bimgame.learn.common.LearnerSettings`, DAgger's through its config): one place for the rules
that tie ``num_mazes``/``start_maze`` to the task and to the network that reads the maze encoding, and
the env arguments every env a run builds gets from them (on the labyrinth: its observation extras and
the env rules a run may change, checked here too — the off-path rule and the reward of a fall;
:func:`stored_off_path_rule` reads the rule back from a run's ``config.json``)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from bimgame.envs.labyrinth_env import LABYRINTH_OFF_PATH_RULES, OBSERVATION_EXTRAS
from bimgame.envs.puzzles import puzzle
from bimgame.learn.learner_settings import check_puzzle
from bimgame.util.settings import require_int

__all__ = [
    "check_env_rules",
    "check_off_path_rule",
    "maze_network",
    "maze_options",
    "network_env_options",
    "run_rules",
    "stored_off_path_rule",
    "LABYRINTH_RULES",
]

#: The blocks of a run's ``config.json`` that hold a learner's flat settings (PPO's, A3C's, DAgger's).
_LEARNER_BLOCKS = ("ppo", "a3c", "dagger")
#: The labyrinth env's rules a run's settings may set, as fields of the same names (None: the env's own).
LABYRINTH_RULES = ("off_path_rule", "fail_reward")


def maze_network(owner: str, task: str, network: Any, *, num_mazes: int | None, start_maze: int) -> Any:
    """Check a run's random mazes (``num_mazes``, ``start_maze``) against its ``task`` and ``network``
    (raising ``ValueError`` naming ``owner``'s setting) and return the network it trains: a state
    network on mazes reads their encoding (``maze_encoding`` derived, as the sizes' defaults are), one
    on MERL's maze alone may neither read nor turn it. Every learner's settings with mazes check here."""
    require_int(owner, "num_mazes", num_mazes, 0, optional=True)
    require_int(owner, "start_maze", start_maze, 0)
    check_puzzle(owner, task, network, num_mazes=num_mazes, start_maze=start_maze)
    if num_mazes is None and start_maze:
        raise ValueError(f"{owner}.start_maze {start_maze} needs num_mazes (the training mazes' count)")
    if not hasattr(network, "maze_encoding"):  # not a NetworkSettings (no network part)
        return network
    if network.obs == "state":
        if num_mazes is not None and not network.maze_encoding:
            return dataclasses.replace(network, maze_encoding=True)
        if num_mazes is None and network.maze_encoding:
            raise ValueError(
                f"{owner}: network.maze_encoding without num_mazes (the encoding is of the episodes' mazes)"
            )
    if num_mazes is None and network.gate_bearings:
        raise ValueError(
            f"{owner}: network.gate_bearings without num_mazes (they are part of the observations on many mazes)"
        )
    if num_mazes is None and network.maze_frame != "board":
        raise ValueError(
            f"{owner}: network.maze_frame {network.maze_frame!r} without num_mazes (it turns the encoding of "
            f"the episodes' mazes, which runs on MERL's maze alone do not observe)"
        )
    return network


def check_off_path_rule(owner: str, task: str, rule: Any) -> None:
    """Raise ``ValueError`` unless ``rule`` is None (the env's default) or one of the labyrinth's
    off-path rules (:data:`~bimgame.envs.labyrinth_env.LABYRINTH_OFF_PATH_RULES`) on a labyrinth task:
    the circular maze has no path to leave."""
    if rule is None:
        return
    if rule not in LABYRINTH_OFF_PATH_RULES:
        raise ValueError(f"{owner}.off_path_rule must be one of {LABYRINTH_OFF_PATH_RULES} or None, got {rule!r}")
    if puzzle(task).is_maze:
        raise ValueError(
            f"{owner}.off_path_rule applies to the labyrinth's tasks only, not {task}: the circular maze has no "
            f"printed path to leave"
        )


def check_env_rules(owner: str, task: str, off_path_rule: Any, fail_reward: Any) -> None:
    """The labyrinth's env rules a learner's settings may change: ``off_path_rule``
    (:func:`check_off_path_rule`) and ``fail_reward``, the training reward of a step that falls into a
    hole or leaves the path (None: the env's, CyberRunner's 0; a finite number on a labyrinth task)."""
    check_off_path_rule(owner, task, off_path_rule)
    if fail_reward is None:
        return
    if not (isinstance(fail_reward, (int, float)) and not isinstance(fail_reward, bool) and math.isfinite(fail_reward)):
        raise ValueError(f"{owner}.fail_reward must be a finite number or None, got {fail_reward!r}")
    if puzzle(task).is_maze:
        raise ValueError(
            f"{owner}.fail_reward applies to the labyrinth's tasks only, not {task}: the maze's episodes "
            f"end at its centre, not in holes"
        )


def run_rules(settings: Any) -> dict[str, Any]:
    """The :data:`LABYRINTH_RULES` of a run's ``settings`` (None for one its class lacks: the env's own,
    which :func:`maze_options` leaves out)."""
    return {name: getattr(settings, name, None) for name in LABYRINTH_RULES}


def maze_options(
    num_mazes: int | None,
    start_maze: int,
    *,
    gate_bearings: bool = False,
    extras: tuple[str, ...] = (),
    rules: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The env arguments of a run's random mazes (empty on MERL's maze alone); ``gate_bearings``: the
    observations hold them (the network reads them: ``NetworkSettings.gate_bearings``). On the
    labyrinth (no mazes), ``extras``: the parts its observations add
    (:data:`~bimgame.envs.labyrinth_env.OBSERVATION_EXTRAS`: ``surroundings`` to the state, ``motion``
    to CyberRunner's; ``NetworkSettings`` switches of the same names), and the env ``rules`` asked for
    (:data:`LABYRINTH_RULES`; one that is None is the env's own and left out, so that earlier runs' env
    arguments are unchanged)."""
    if num_mazes is None:
        return {**dict.fromkeys(extras, True), **{k: v for k, v in (rules or {}).items() if v is not None}}
    return {"num_mazes": num_mazes, "start_maze": start_maze, **({"gate_bearings": True} if gate_bearings else {})}


def network_env_options(
    network: Any, num_mazes: int | None = None, start_maze: int = 0, rules: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """The env arguments of a run on ``num_mazes`` mazes (from ``start_maze``) whose ``network`` (network
    settings, or None) reads what it reads: gate bearings on mazes, the labyrinth's surroundings or motion
    (:func:`maze_options` with the network's own switches), and the labyrinth's env ``rules`` (a run's:
    :func:`run_rules`). Every place that builds envs for a network asks here."""
    return maze_options(
        num_mazes,
        start_maze,
        gate_bearings=bool(getattr(network, "gate_bearings", False)),
        extras=tuple(name for name in OBSERVATION_EXTRAS if getattr(network, name, False)),
        rules=rules,
    )


def stored_off_path_rule(stored: dict[str, Any]) -> str | None:
    """The labyrinth's off-path rule a run trained under, from its ``config.json`` (``stored``): its
    learner's ``off_path_rule`` (``bimgame train`` or ``bimgame dagger --off-path-rule``); None (the env's
    default) for runs without one — pre-training and every run written before the setting."""
    for name in _LEARNER_BLOCKS:
        block = stored.get(name)
        if isinstance(block, dict) and block.get("off_path_rule") is not None:
            return str(block["off_path_rule"])
    return None
