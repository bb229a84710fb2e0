"""A3C with privileged information and augmentation: auxiliary heads, an asymmetric critic, random
shifts, and bf16 — the loss terms, and runs that use them end to end."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from bimgame.learn.a3c import A3CConfig, a3c_segment_loss, apply_update, make_optimizer, network_for, train
from bimgame.learn.checkpoints import load_checkpoint
from bimgame.learn.finetune import LossWeights
from bimgame.learn.nets import LSTMState, state_obs_scale
from bimgame.learn.rollout import Segment
from bimgame.sim.maze import MazeSpec

PIXELS = dict(task="STG1", obs="pixels", workers=1, envs_per_worker=2, n_steps=5, eval_every=0, hidden=16,
              features=16, log_every=100)


def _segment(config: A3CConfig, steps: int, batch: int, seed: int = 0) -> Segment:
    g = torch.Generator().manual_seed(seed)
    scale = torch.as_tensor(state_obs_scale(MazeSpec.merl()))
    return Segment(**{"obs": torch.randint(0, 256, (steps + 1, batch, 1, 84, 84), generator=g, dtype=torch.uint8),
            "prev_action": torch.randint(-1, 5, (steps + 1, batch), generator=g),
            "prev_reward": torch.zeros(steps + 1, batch), "tilt": torch.zeros(steps + 1, batch, 2),
            "starts": torch.zeros(steps + 1, batch, dtype=torch.bool),
            "privileged": (torch.rand(steps + 1, batch, 7, generator=g) * 2 - 1) * scale,
            "actions": torch.randint(0, 5, (steps, batch), generator=g),
            "rewards": (torch.rand(steps, batch, generator=g) < 0.2).float(),
            "ends": torch.rand(steps, batch, generator=g) < 0.15,
            "initial_state": LSTMState(torch.zeros(batch, config.network.hidden),
                                       torch.zeros(batch, config.network.hidden))})


def test_aux_loss_is_added_with_its_weight():
    config = A3CConfig.from_flat(**PIXELS, aux_heads=True)
    net = network_for(config)
    seg = _segment(config, 4, 2)
    loss, parts = a3c_segment_loss(net, seg, config)
    heavier, _ = a3c_segment_loss(net, seg, A3CConfig.from_flat(**PIXELS, aux_heads=True, aux_coef=3.0))
    assert parts["aux_frame"] > 0 and parts["aux_memory"] > 0
    assert heavier.item() - loss.item() == pytest.approx(2.0 * (parts["aux_frame"] + parts["aux_memory"]), rel=1e-4)
    without = seg.replace(privileged=None)
    with pytest.raises(ValueError, match="privileged"):
        a3c_segment_loss(net, without, config)


def test_critic_warmup_trains_the_whole_asymmetric_critic_and_nothing_else():
    config = A3CConfig.from_flat(**PIXELS, asymmetric_critic=True, critic_warmup_steps=1000)
    local, shared = network_for(config), network_for(config)
    optimizer = make_optimizer(config, shared)
    before = {k: v.clone() for k, v in shared.state_dict().items()}
    apply_update(local, list(shared.parameters()), optimizer, _segment(config, 4, 2), config,
                 LossWeights(actor=0.0, critic_only=True))
    after = shared.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed and all(k.startswith(("value.", "critic_state.")) for k in changed), changed
    assert any(k.startswith("critic_state.") for k in changed)


def test_privileged_settings_are_checked():
    with pytest.raises(ValueError, match="augment_shift"):
        A3CConfig.from_flat(obs="pixels", augment_shift=3)
    with pytest.raises(ValueError, match="augment_shift"):
        A3CConfig.from_flat(obs="state", augment_shift=1)
    with pytest.raises(ValueError, match="aux_coef"):
        A3CConfig.from_flat(aux_coef=-1.0)
    with pytest.raises(ValueError, match="precision"):
        A3CConfig.from_flat(precision="fp8")


def test_pixel_run_with_every_lever_logs_the_aux_losses_and_is_deterministic(tmp_path):
    # time limits: the critic bootstraps from the state
    config = A3CConfig.from_flat(**PIXELS, steps=300, seed=2, aux_heads=True, asymmetric_critic=True,
                                 augment_shift=2, precision="bf16", max_episode_steps=20)
    train(config, tmp_path / "a", progress=False)
    train(config, tmp_path / "b", progress=False)
    a, b = load_checkpoint(tmp_path / "a"), load_checkpoint(tmp_path / "b")
    for key in a["model"]:
        assert torch.equal(a["model"][key], b["model"][key]), key
    rows = list(csv.DictReader(open(tmp_path / "a" / "updates.csv")))
    assert rows
    for row in rows:
        assert np.isfinite(float(row["aux_frame"])) and np.isfinite(float(row["aux_memory"]))
        assert np.isfinite(float(row["value_loss"]))  # the asymmetric critic got its states, even at time limits


def test_runs_without_privileged_parts_log_no_aux_loss(tmp_path):
    config = A3CConfig.from_flat(task="STG1", obs="state", workers=1, envs_per_worker=2, n_steps=5, eval_every=0,
                                 hidden=8, features=8, log_every=20, steps=200)
    train(config, tmp_path / "run", progress=False)
    rows = list(csv.DictReader(open(tmp_path / "run" / "updates.csv")))
    assert rows and all(row["aux_frame"] == "nan" and row["aux_memory"] == "nan" for row in rows)


def test_pixel_defaults_are_the_measured_best_and_state_defaults_unchanged():
    from bimgame.learn.common import native_bf16
    pixels, state = A3CConfig.from_flat(obs="pixels").network, A3CConfig.from_flat(obs="state").network
    assert (pixels.aux_heads, pixels.asymmetric_critic) == (True, False)
    assert pixels.precision == ("bf16" if native_bf16() else "fp32")
    assert (state.aux_heads, state.asymmetric_critic, state.precision) == (False, False, "fp32")
    explicit = A3CConfig.from_flat(obs="pixels", aux_heads=False, asymmetric_critic=False, precision="fp32").network
    assert (explicit.aux_heads, explicit.asymmetric_critic, explicit.precision) == (False, False, "fp32")


def test_a_pixel_run_stored_before_the_privileged_settings_resumes_as_the_papers_network(tmp_path):
    """A config.json without aux_heads / asymmetric_critic / precision was written when every network
    was the paper's: it reads back as that network (whose weights the checkpoint holds), not as
    today's pixel default."""
    import json

    from bimgame.learn.a3c import resolve_config
    from bimgame.learn.common import read_run
    config = A3CConfig.from_flat(**{**PIXELS, "hidden": 8, "features": 8}, steps=40, aux_heads=False,
                                 asymmetric_critic=False, precision="fp32")
    train(config, tmp_path / "old", progress=False)
    stored = json.loads((tmp_path / "old" / "config.json").read_text())
    for name in ("aux_heads", "asymmetric_critic", "precision"):
        del stored["a3c"][name]
    (tmp_path / "old" / "config.json").write_text(json.dumps(stored))
    resumed = resolve_config({"steps": 80}, tmp_path / "old", resume=True)
    network = resumed.network
    assert (network.aux_heads, network.asymmetric_critic, network.precision) == (False, False, "fp32")
    assert not read_run(tmp_path / "old").network.aux_heads
    train(resumed, tmp_path / "old", resume=True, progress=False)  # the stored weights load into it
    assert load_checkpoint(tmp_path / "old")["step"] >= 80
