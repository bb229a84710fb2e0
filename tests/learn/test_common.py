"""What the learners share: network settings, reading a run directory (current and earlier layouts),
``--init`` checks, loading a run's network and the evaluation seed."""

from __future__ import annotations

import json

import pytest
import torch

from bimgame.learn.a3c import A3CConfig
from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.common import (
    NetworkSettings,
    evaluation_seed,
    init_network_settings,
    load_run_network,
    network_settings_of,
    read_run,
)
from bimgame.learn.runs import CHECKPOINT, KIND_A3C, KIND_POLICY, KIND_VALUE
from bimgame.learn.supervised import PretrainConfig

SMALL = NetworkSettings(obs="state", hidden=8, features=8)


def _write_config(run_dir, config: dict):
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.json").write_text(json.dumps(config))
    return run_dir


def _current_layout(network: NetworkSettings = SMALL, *, kind: str = KIND_POLICY, task: str = "STG1",
                    seed: int = 0, **extra) -> dict:
    return {"kind": kind, "task": task, "seed": seed, "network": network.to_dict(), **extra}


# --- NetworkSettings -----------------------------------------------------------------------------


def test_sizes_default_by_observation():
    pixels = NetworkSettings()
    assert (pixels.obs, pixels.hidden, pixels.features) == ("pixels", 256, 256)
    state = NetworkSettings(obs="state")
    assert (state.hidden, state.features) == (128, 128)
    assert NetworkSettings(obs="state", hidden=32).features == 128
    assert NetworkSettings(obs="pixels", features=64).hidden == 256


@pytest.mark.parametrize("values, field", [({"obs": "rgb"}, "obs"), ({"hidden": 0}, "hidden"),
                                           ({"features": -4}, "features"), ({"hidden": 2.0}, "hidden"),
                                           ({"hidden": True}, "hidden"), ({"tilt_input": 1}, "tilt_input"),
                                           ({"keypoints": "yes"}, "keypoints")])
def test_bad_network_settings_name_the_field(values, field):
    with pytest.raises(ValueError, match=rf"NetworkSettings\.{field}"):
        NetworkSettings(**values)


def test_a_learners_settings_name_their_own_class():
    with pytest.raises(ValueError, match=r"NetworkSettings\.hidden"):
        A3CConfig.from_flat(hidden=0)
    with pytest.raises(ValueError, match=r"PretrainConfig\.obs"):
        PretrainConfig(obs="rgb")


def test_learners_give_equal_network_settings_for_equal_network_fields():
    fields = dict(obs="state", hidden=48, features=24, tilt_input=False, keypoints=False, subtract_background=False)
    a3c = A3CConfig.from_flat(task="STG2", steps=1000, **fields).network
    pretrain = PretrainConfig(task="STG3", epochs=2, **fields).network_settings()
    assert type(a3c) is NetworkSettings and type(pretrain) is NetworkSettings
    assert a3c == pretrain == NetworkSettings(**fields)
    assert A3CConfig.from_flat(obs="state").network == PretrainConfig(obs="state").network_settings()
    assert A3CConfig.from_flat(obs="state").network != PretrainConfig(obs="state", hidden=64).network_settings()


def test_network_settings_dict_round_trip_and_unknown_keys():
    settings = NetworkSettings(obs="state", hidden=16, keypoints=True)
    assert NetworkSettings.from_dict(settings.to_dict()) == settings
    with pytest.raises(ValueError, match="'lstm'"):
        NetworkSettings.from_dict({"obs": "state", "lstm": 3})
    # a flat settings dict: the network keys are picked, the rest ignored
    assert network_settings_of({"obs": "state", "hidden": 16, "keypoints": True, "lr": 0.1}) == settings


# --- read_run ------------------------------------------------------------------------------------


def test_read_run_current_layout(tmp_path):
    network = NetworkSettings(obs="state", hidden=16)
    run_dir = _write_config(tmp_path / "run", _current_layout(network, task="stg2", seed=3))
    run = read_run(run_dir)
    assert run.run_dir == run_dir and run.kind == KIND_POLICY
    assert run.task == "STG2" and run.seed == 3
    assert run.network == network and run.network.features == 128
    assert run.time_limit == 500  # STG2's registered limit
    assert run.config["network"]["hidden"] == 16
    # a file inside the run names the same run
    (run_dir / CHECKPOINT).write_bytes(b"")
    assert read_run(run_dir / CHECKPOINT).run_dir == run_dir


def test_read_run_current_layout_with_a_time_limit(tmp_path):
    run_dir = _write_config(tmp_path / "run", _current_layout(max_episode_steps=123))
    assert read_run(run_dir).time_limit == 123


def test_read_run_earlier_layout(tmp_path):
    block = {"task": "STG1", "obs": "state", "hidden": 32, "features": 16, "tilt_input": False, "seed": 5,
             "max_episode_steps": 200, "lr": 0.001, "epochs": 3}
    run_dir = _write_config(tmp_path / "old", {"kind": KIND_POLICY, "a3c": block})
    run = read_run(run_dir)
    assert run.kind == KIND_POLICY and run.task == "STG1" and run.seed == 5 and run.time_limit == 200
    assert run.network == NetworkSettings(obs="state", hidden=32, features=16, tilt_input=False)


def test_read_run_a3c_config_without_a_kind(tmp_path):
    config = A3CConfig.from_flat(task="STG3", obs="state", hidden=8, features=8, seed=11)
    run_dir = _write_config(tmp_path / "a3c", {"a3c": config.to_dict()})  # as bimgame train writes it
    run = read_run(run_dir)
    assert run.kind == KIND_A3C and run.task == "STG3" and run.seed == 11 and run.time_limit == 750
    assert run.network == config.network


def test_read_run_without_config_names_config_json(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="config.json"):
        read_run(tmp_path / "empty")


def test_read_run_without_task_or_network_says_what_is_missing(tmp_path):
    run_dir = _write_config(tmp_path / "odd", {"kind": KIND_POLICY, "network": SMALL.to_dict()})
    with pytest.raises(ValueError, match="names no task and network"):
        read_run(run_dir)


def test_read_run_refuses_unknown_network_keys_and_bad_tasks(tmp_path):
    run_dir = _write_config(tmp_path / "a", {"task": "STG1", "network": {"obs": "state", "depth": 3}})
    with pytest.raises(ValueError, match="'depth'"):
        read_run(run_dir)
    run_dir = _write_config(tmp_path / "b", _current_layout(task="STG9"))
    with pytest.raises(ValueError, match="STG9"):
        read_run(run_dir)


# --- init_network_settings -----------------------------------------------------------------------


def test_init_from_a_bare_checkpoint_outside_a_run_is_empty(tmp_path):
    net = SMALL.build_policy(0)
    path = save_checkpoint(tmp_path / "loose" / "weights.pt", model=net.state_dict(), step=1)
    assert init_network_settings(path) == {}
    assert init_network_settings(path.parent) == {}


def test_init_from_a_run_gives_its_network_settings(tmp_path):
    network = NetworkSettings(obs="state", hidden=24, keypoints=False)
    run_dir = _write_config(tmp_path / "run", _current_layout(network))
    assert init_network_settings(run_dir) == network.to_dict()
    (run_dir / CHECKPOINT).write_bytes(b"")
    assert init_network_settings(run_dir / CHECKPOINT)["hidden"] == 24


def test_init_refuses_a_missing_path(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        init_network_settings(tmp_path / "nowhere")


def test_init_refuses_a_value_function_run(tmp_path):
    run_dir = _write_config(tmp_path / "value", _current_layout(kind=KIND_VALUE))
    with pytest.raises(ValueError, match="--value-reward"):
        init_network_settings(run_dir)


# --- load_run_network ----------------------------------------------------------------------------


def test_load_run_network_restores_the_weights_and_step(tmp_path):
    source = SMALL.build_policy(0)
    with torch.no_grad():
        for param in source.parameters():
            param.add_(0.25)  # weights no fresh initialisation has
    run_dir = _write_config(tmp_path / "run", _current_layout(SMALL, seed=1))
    save_checkpoint(run_dir / CHECKPOINT, model=source.state_dict(), step=7)
    for where in (run_dir, run_dir / CHECKPOINT):
        net, run, step = load_run_network(where)
        assert step == 7 and run.run_dir == run_dir and run.network == SMALL
        loaded = net.state_dict()
        assert loaded.keys() == source.state_dict().keys()
        for name, tensor in source.state_dict().items():
            assert torch.equal(loaded[name], tensor), name
    fresh = SMALL.build_policy(1).state_dict()  # what the run's seed alone would give
    assert not all(torch.equal(fresh[k], v) for k, v in source.state_dict().items())


def test_load_run_network_refuses_a_directory_that_is_no_run(tmp_path):
    (tmp_path / "plain").mkdir()
    with pytest.raises(ValueError, match="config.json"):
        load_run_network(tmp_path / "plain")


def test_load_run_network_refuses_a_value_function(tmp_path):
    run_dir = _write_config(tmp_path / "value", _current_layout(kind=KIND_VALUE))
    with pytest.raises(ValueError, match="value function"):
        load_run_network(run_dir)


def test_load_run_network_refuses_weights_of_another_shape(tmp_path):
    other = NetworkSettings(obs="state", hidden=12, features=8).build_policy(0)
    run_dir = _write_config(tmp_path / "run", _current_layout(SMALL))
    save_checkpoint(run_dir / CHECKPOINT, model=other.state_dict(), step=1)
    with pytest.raises(ValueError, match="do not fit"):
        load_run_network(run_dir)


# --- evaluation_seed -----------------------------------------------------------------------------


def test_evaluation_seed_is_deterministic_and_differs_between_seeds():
    assert evaluation_seed(0) == evaluation_seed(0)
    assert evaluation_seed(123) == evaluation_seed(123)
    seeds = [evaluation_seed(s) for s in range(20)]
    assert len(set(seeds)) == 20
    assert all(isinstance(s, int) and s >= 0 for s in seeds)
    assert evaluation_seed(5) != 5
