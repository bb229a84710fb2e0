"""Starting a learner from another run's policy (``--init``: a pre-trained π^s, an A3C or a PPO run):
the network the learner builds must be the network those weights were trained as.

The weights' shapes catch most differences, but an error about a tensor's shape does not say which
setting differs or what to do, and some settings change what the inputs mean without changing a
shape (background subtraction). So the settings are compared first, by name. Two differences are
allowed, the parts that only train: a run may add an asymmetric critic to a policy trained without
one (a π^s or DAgger iterate never has one), which grows out of the old value head, and auxiliary
heads (a DAgger iterate never has them), which start fresh; neither changes what the policy does.
The maze encoding gets its own advice: a policy pre-trained on a dataset of many mazes (``bimgame
generate --num-mazes``) reads each episode's maze encoding and starts runs on many mazes
(``--num-mazes``) only; one of MERL's maze alone does not read it and cannot start them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bimgame.learn.common import NetworkSettings, init_network_settings, read_run

__all__ = ["MATCHED_SETTINGS", "TRAINING_PARTS", "check_init_network", "init_settings_for"]

#: The network settings that decide the weights or what their inputs mean (``precision`` is only how
#: they are computed).
MATCHED_SETTINGS = tuple(name for name in NetworkSettings.field_names() if name != "precision")

_LACKS_ENCODING = (
    "this run on many mazes (num_mazes) reads the maze encoding, which that network, trained on "
    "MERL's maze alone, does not: pre-train on a dataset generated with --num-mazes "
    "(bimgame generate --num-mazes N), or train without --num-mazes"
)


def init_settings_for(init: str | Path, num_mazes: int | None) -> dict[str, Any]:
    """The network settings of the run ``init`` points at (:func:`~bimgame.learn.common.init_network_settings`,
    what a run started from it takes unless given), refused with advice when that network reads the
    maze encoding and the run has no ``num_mazes`` (the learner's settings would only say that the
    encoding needs ``num_mazes``)."""
    settings = init_network_settings(init)
    if settings.get("maze_encoding") and num_mazes is None:
        raise ValueError(
            f"--init: the network of {init} does not fit a run on MERL's maze alone: {_reads_encoding(init)}"
        )
    return settings


def check_init_network(init: str | Path | None, network: NetworkSettings) -> None:
    """Refuse to start a run whose network is ``network`` from the weights of ``init`` when the run
    that wrote them names other network settings (:data:`MATCHED_SETTINGS`); the error names each
    setting, both values and what to do. A bare checkpoint file outside a run names none: only its
    shapes are checked (when the weights are loaded)."""
    if init is None:
        return
    stored = init_network_settings(init)
    if not stored:
        return
    theirs = NetworkSettings.from_dict(stored)
    differing = [
        name
        for name in MATCHED_SETTINGS
        if getattr(theirs, name) != getattr(network, name) and not _adds_training_part(name, theirs, network)
    ]
    if not differing:
        return
    shown = "; ".join(f"{name}: {getattr(theirs, name)!r} there, {getattr(network, name)!r} here" for name in differing)
    if "maze_encoding" in differing:
        advice = _reads_encoding(init) if theirs.maze_encoding else _LACKS_ENCODING
    else:
        advice = "leave those settings out to take the network's, or start from a network with this run's settings"
    raise ValueError(f"--init: the network of {init} is not this run's ({shown}): {advice}")


#: The network parts that only train (the policy does not read them), which a run may add to a policy
#: trained without them: an asymmetric critic and auxiliary heads (:mod:`bimgame.learn.checkpoints`
#: fits the old weights to them).
TRAINING_PARTS = ("asymmetric_critic", "aux_heads")


def _adds_training_part(name: str, theirs: NetworkSettings, network: NetworkSettings) -> bool:
    """Whether setting ``name`` differs only because the run adds a part of :data:`TRAINING_PARTS`
    to a policy trained without it: allowed, the critic grows out of the old one's value head
    (:func:`~bimgame.learn.checkpoints.with_added_critic`) and the heads start fresh
    (:func:`~bimgame.learn.checkpoints.with_added_aux_heads`); dropping a trained part is not."""
    return name in TRAINING_PARTS and getattr(network, name) and not getattr(theirs, name)


def _reads_encoding(init: str | Path) -> str:
    """Advice for a network that reads the maze encoding, naming the mazes its run recorded."""
    config = read_run(init).config
    flags = "--num-mazes N"
    for block in (config, config.get("a3c"), config.get("ppo")):  # π^s's own keys, or a learner's settings
        if isinstance(block, dict) and block.get("num_mazes") is not None:
            flags = f"--num-mazes {block['num_mazes']} --start-maze {block.get('start_maze', 0)}"
            break
    return (
        "it reads the maze encoding (it was trained on many mazes: pre-trained on a dataset generated with "
        f"--num-mazes, or a run with --num-mazes), so it starts runs on many mazes only: give this run {flags} "
        "(the mazes it was trained on)"
    )
