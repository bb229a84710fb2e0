"""Fine-tuning methods: their schedules, the KL to the teacher, the critic warm-up, advantage scaling,
the behaviour-cloning term, the presets, and a fine-tuned run end to end."""

from __future__ import annotations

import copy
import csv
import json

import numpy as np
import pytest
import torch

from bimgame.expert.datasets import generate_dataset
from bimgame.expert.episode import Episode
from bimgame.learn.a3c import A3CConfig, apply_update, make_optimizer, network_for, resolve_config, train
from bimgame.learn.a3c.update import a3c_segment_loss
from bimgame.learn.checkpoints import save_checkpoint
from bimgame.learn.finetune import (
    DemoWindows,
    EntropyTarget,
    LossWeights,
    RunningScale,
    Teacher,
    bc_loss,
    kl_to_teacher,
    loss_weights,
)
from bimgame.learn.learner_settings import FINETUNE_PRESETS
from bimgame.learn.nets import LSTMState
from bimgame.learn.rollout import Segment

SMALL = dict(obs="state", hidden=16, features=16)


def _segment(config: A3CConfig, steps: int, batch: int, seed: int = 0) -> Segment:
    g = torch.Generator().manual_seed(seed)
    starts = torch.zeros(steps + 1, batch, dtype=torch.bool)
    starts[0] = True
    starts[steps // 2, 0] = True
    return Segment(**{"obs": torch.randn(steps + 1, batch, 7, generator=g) * 0.05,
            "prev_action": torch.randint(0, 5, (steps + 1, batch), generator=g),
            "prev_reward": torch.zeros(steps + 1, batch), "tilt": torch.zeros(steps + 1, batch, 2),
            "starts": starts, "actions": torch.randint(0, 5, (steps, batch), generator=g),
            "rewards": (torch.rand(steps, batch, generator=g) < 0.2).float(),
            "ends": starts[1:].clone(),
            "initial_state": LSTMState(torch.zeros(batch, config.network.hidden),
                                       torch.zeros(batch, config.network.hidden))})


def test_schedules_warm_up_ramp_and_decay():
    config = A3CConfig.from_flat(**SMALL, critic_warmup_steps=100, actor_ramp_steps=200, kl_coef=2.0,
                                 kl_decay_steps=1000, bc_coef=0.5, bc_decay_steps=400, expert_data="unused")
    settings = config.finetuning
    assert loss_weights(settings, 0) == LossWeights(actor=0.0, kl=2.0, bc=0.5, critic_only=True)
    assert loss_weights(settings, 99).critic_only
    middle = loss_weights(settings, 200)
    assert not middle.critic_only and middle.actor == pytest.approx(0.5)
    assert middle.kl == pytest.approx(2.0 * 0.8) and middle.bc == pytest.approx(0.5 * 0.5)
    late = loss_weights(settings, 5000)
    assert late == LossWeights(actor=1.0, kl=0.0, bc=0.0, critic_only=False)
    plain = loss_weights(A3CConfig.from_flat(**SMALL).finetuning, 0)
    assert plain == LossWeights(actor=1.0, kl=0.0, bc=0.0, critic_only=False)


def test_kl_is_zero_for_the_teacher_itself_and_positive_otherwise():
    config = A3CConfig.from_flat(**SMALL)
    student = network_for(config)
    seg = _segment(config, 8, 3)
    teacher = Teacher(copy.deepcopy(student), 3)
    teacher_log_probs = teacher.follow(seg)
    logits, _, _ = student.unroll(seg.obs, seg.prev_action, seg.prev_reward, seg.tilt, seg.initial_state,
                                  seg.starts)
    log_probs = torch.log_softmax(logits[:-1], dim=-1)
    kl = kl_to_teacher(teacher_log_probs, log_probs)
    assert kl.item() == pytest.approx(0.0, abs=1e-7)
    kl.backward()
    assert max(float(p.grad.abs().max()) for p in student.parameters() if p.grad is not None) < 1e-6
    with torch.no_grad():
        student.policy.bias += torch.tensor([1.0, 0.0, 0.0, -1.0, 0.5])
    logits, _, _ = student.unroll(seg.obs, seg.prev_action, seg.prev_reward, seg.tilt, seg.initial_state,
                                  seg.starts)
    assert kl_to_teacher(teacher_log_probs, torch.log_softmax(logits[:-1], dim=-1)).item() > 0.05


def test_teacher_carries_its_lstm_state_across_segments():
    """Following two consecutive segments gives the same distributions as following one long one."""
    config = A3CConfig.from_flat(**SMALL)
    net = network_for(config)
    whole = _segment(config, 10, 2, seed=3)
    inputs = ("obs", "prev_action", "prev_reward", "tilt", "starts")
    first = whole.replace(**{k: getattr(whole, k)[:6] for k in inputs}, actions=whole.actions[:5])
    second = whole.replace(**{k: getattr(whole, k)[5:] for k in inputs}, actions=whole.actions[5:])
    one = Teacher(copy.deepcopy(net), 2).follow(whole)
    split = Teacher(copy.deepcopy(net), 2)
    both = torch.cat([split.follow(first), split.follow(second)])
    assert torch.allclose(one, both, atol=1e-6)


def test_critic_warm_up_changes_only_the_value_head_and_the_ramp_scales_the_policy_learning_rate():
    config = A3CConfig.from_flat(**SMALL, critic_warmup_steps=1000, actor_ramp_steps=1000, lr=1e-2)
    shared = network_for(config)
    local = copy.deepcopy(shared)
    optimizer = make_optimizer(config, shared)
    assert [len(g["params"]) for g in optimizer.param_groups] == [2, len(list(shared.parameters())) - 2]
    before = {k: v.clone() for k, v in shared.state_dict().items()}
    parts = apply_update(local, list(shared.parameters()), optimizer, _segment(config, 8, 3), config,
                         loss_weights(config.finetuning, 0))
    assert parts["applied"]
    changed = {k for k, v in shared.state_dict().items() if not torch.equal(v, before[k])}
    assert changed == {"value.weight", "value.bias"}
    apply_update(local, list(shared.parameters()), optimizer, _segment(config, 8, 3, seed=1), config,
                 loss_weights(config.finetuning, 1500))
    assert optimizer.param_groups[0]["lr"] == pytest.approx(0.5e-2)
    assert optimizer.param_groups[1]["lr"] == pytest.approx(1e-2)
    assert not torch.equal(shared.state_dict()["policy.weight"], before["policy.weight"])


def test_advantage_scaling_makes_the_policy_gradient_independent_of_the_reward_scale():
    """Rewards ×1000 and a critic that is scaled alike: with advantage scaling the policy loss is the
    same; without it, it is 1000 times larger."""
    config = A3CConfig.from_flat(**SMALL, value_coef=0.0, entropy_coef=0.0)
    net = network_for(config)
    seg = _segment(config, 8, 4)
    big = seg.replace(rewards=seg.rewards * 1000)
    with torch.no_grad():
        net.value.weight.zero_()
        net.value.bias.zero_()
    losses = {}
    for name, segment in (("small", seg), ("big", big)):
        for scaled in (False, True):
            _, parts = a3c_segment_loss(net, segment, config, advantage_scale=RunningScale() if scaled else None)
            losses[name, scaled] = parts["policy_loss"]
    assert losses["big", False] == pytest.approx(1000 * losses["small", False], rel=1e-4)
    assert losses["big", True] == pytest.approx(losses["small", True], rel=1e-4)


def _episodes(count: int, length: int, rng: np.random.Generator) -> list[Episode]:
    episodes = []
    for i in range(count):
        obs = rng.normal(size=(length, 7)).astype(np.float32)
        actions = (obs[:, 0] > 0).astype(np.int64) * 2 + 1  # the expert's action follows the observation
        episodes.append(Episode.from_steps(obs=obs, actions=actions, rewards=np.zeros(length), tilt=np.zeros((length, 2)),
                                           gamma=0.99, id=i))
    return episodes


def test_demo_windows_are_slices_of_the_episodes_and_the_bc_term_learns_them():
    rng = np.random.default_rng(0)
    episodes = _episodes(4, 60, rng)
    windows = DemoWindows(episodes, max_tilt=0.1, length=20, burn_in=5)
    batch = windows.sample(6, np.random.default_rng(1))
    assert batch["obs"].shape == (20, 6, 7) and batch["actions"].shape == (20, 6)
    for b in range(6):  # each column is a contiguous slice of one episode
        column = batch["obs"][:, b].numpy()
        matches = [e for e in episodes if any(np.array_equal(column[0], row) for row in e.obs)]
        assert len(matches) == 1
        start = next(t for t, row in enumerate(matches[0].obs) if np.array_equal(column[0], row))
        n = min(20, len(matches[0]) - start)
        assert np.array_equal(column[:n], matches[0].obs[start:start + n])
        assert np.array_equal(batch["actions"][:n, b].numpy(), matches[0].actions[start:start + n])
        assert not batch["mask"][n:, b].any()
    assert np.array_equal(windows.sample(6, np.random.default_rng(1))["obs"].numpy(), batch["obs"].numpy())
    torch.manual_seed(0)
    net = network_for(A3CConfig.from_flat(**SMALL))
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    sample_rng = np.random.default_rng(2)
    first = bc_loss(net, windows.sample(8, sample_rng)).item()
    for _ in range(60):
        loss = bc_loss(net, windows.sample(8, sample_rng))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert first > 1.4 and bc_loss(net, windows.sample(32, sample_rng)).item() < 0.5 * first


def test_presets_apply_with_init_and_yield_to_given_settings(tmp_path):
    init = tmp_path / "pi.pt"
    config = A3CConfig.from_flat(**SMALL)
    save_checkpoint(init, model=network_for(config).state_dict(), step=0)
    default = resolve_config({"obs": "state"}, tmp_path / "run", init=init)
    assert default.finetuning is not None and default.finetuning.finetune == "keep"
    assert {k: default.to_dict()[k] for k in FINETUNE_PRESETS["keep"]} == FINETUNE_PRESETS["keep"]
    paper = resolve_config({"obs": "state", "finetune": "paper"}, tmp_path / "run", init=init)
    assert {k: paper.to_dict()[k] for k in FINETUNE_PRESETS["paper"]} == FINETUNE_PRESETS["paper"]
    mixed = resolve_config({"obs": "state", "kl_coef": 0.25}, tmp_path / "run", init=init)
    assert mixed.finetuning is not None and mixed.finetuning.kl_coef == 0.25
    assert mixed.finetuning.critic_warmup_steps == FINETUNE_PRESETS["keep"]["critic_warmup_steps"]
    scratch = resolve_config({"obs": "state"}, tmp_path / "run")
    assert scratch.finetuning is None  # no preset (finetune None) and kl_coef 0: no fine-tuning part
    with pytest.raises(ValueError, match="finetune must be one of paper, keep, got 'forget'"):
        resolve_config({"obs": "state", "finetune": "forget"}, tmp_path / "run", init=init)
    with pytest.raises(ValueError, match="bc_coef needs expert_data"):
        A3CConfig.from_flat(**SMALL, bc_coef=0.1)
    with pytest.raises(ValueError, match="kl_coef > 0 .* needs a pre-trained policy"):
        train(A3CConfig.from_flat(**SMALL, kl_coef=1.0), tmp_path / "no-teacher", progress=False)
    assert not (tmp_path / "no-teacher").exists()


def test_fine_tuned_run_keeps_its_teacher_logs_the_terms_and_resumes(tmp_path):
    base = dict(task="STG1", workers=1, envs_per_worker=4, n_steps=10, eval_every=0, log_every=200, **SMALL)
    init = tmp_path / "pi.pt"
    teacher_net = network_for(A3CConfig.from_flat(**base, seed=5))
    save_checkpoint(init, model=teacher_net.state_dict(), step=0)
    given = {**base, "steps": 2_000, "critic_warmup_steps": 400, "actor_ramp_steps": 400,
             "kl_decay_steps": 4_000, "checkpoint_every": 1_000}
    config = resolve_config(given, tmp_path / "run", init=init)
    result = train(config, tmp_path / "run", init=init, progress=False)
    assert result.stopped == "finished"
    stored = torch.load(tmp_path / "run" / "teacher.pt", weights_only=True)["model"]
    assert all(torch.equal(stored[k], v) for k, v in teacher_net.state_dict().items())
    with open(tmp_path / "run" / "updates.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert rows and all(float(r["kl"]) >= 0 for r in rows)
    assert float(rows[0]["actor_weight"]) == 0.0 and float(rows[-1]["actor_weight"]) > 0.0
    assert float(rows[-1]["kl_weight"]) < 1.0
    assert json.loads((tmp_path / "run" / "config.json").read_text())["a3c"]["finetune"] == "keep"
    resumed = resolve_config({"steps": 3_000}, tmp_path / "run", resume=True)
    assert train(resumed, tmp_path / "run", resume=True, progress=False).steps >= 3_000


def test_entropy_target_sharpens_above_the_target_and_protects_below_it():
    target = EntropyTarget(final=0.5, steps=1000, initial_coef=0.01, rate=1e-2, bound=0.05)
    assert target.update(1.5, 0) == 0.01  # first update: its entropy is where the target starts
    assert target.target(500) == pytest.approx(1.0) and target.target(5000) == pytest.approx(0.5)
    for _ in range(100):
        coef = target.update(1.5, 1000)  # far above the final target: the coefficient turns into a penalty
    assert coef == pytest.approx(-0.05)  # and stays within its bound
    for _ in range(100):
        coef = target.update(0.1, 1000)  # collapsed below it: a bonus again
    assert coef == pytest.approx(0.05)
    assert target.update(float("nan"), 1000) == coef
    with pytest.raises(ValueError, match="entropy_target must be None or in"):
        A3CConfig.from_flat(**SMALL, entropy_target=2.0)


@pytest.mark.parametrize("curriculum", ["demo", "reverse"])
def test_start_curricula_train_and_keep_training_success_to_the_true_starts(tmp_path, curriculum):
    """A run with a start curriculum logs which episodes began at the task's own starts, counts only
    those in its training success, and reports the curriculum's state with each update."""
    data = None
    if curriculum == "demo":
        data = tmp_path / "data"
        generate_dataset(data, task="STG1", episodes=2, seed=0, workers=1, progress=False)
    config = A3CConfig.from_flat(task="STG1", workers=1, envs_per_worker=4, n_steps=10, eval_every=0, log_every=200,
                                 steps=3_000, start_curriculum=curriculum, expert_data=None if data is None else str(data),
                                 entropy_target=1.0, entropy_target_steps=2_000, **SMALL)
    result = train(config, tmp_path / "run", progress=False)
    assert result.stopped == "finished"
    with open(tmp_path / "run" / "episodes.csv") as handle:
        episodes = list(csv.DictReader(handle))
    kinds = {row["true_start"] for row in episodes}
    assert "False" in kinds  # most episodes start from the curriculum's starts
    with open(tmp_path / "run" / "updates.csv") as handle:
        updates = list(csv.DictReader(handle))
    assert all(row["curriculum_stage"] != "" for row in updates)
    assert float(updates[-1]["entropy_coef"]) != config.optimization.entropy_coef  # the coefficient adapted
    true_starts = [row["success"] == "True" for row in episodes if row["true_start"] == "True"]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    if true_starts:
        recent = true_starts[-100:]
        assert summary["recent_success"] == pytest.approx(sum(recent) / len(recent), abs=0.2)


def test_a_cooler_teacher_is_sharper_with_the_same_greedy_action():
    config = A3CConfig.from_flat(**SMALL)
    net = network_for(config)
    with torch.no_grad():
        net.policy.bias += torch.tensor([0.3, 0.0, -0.2, 0.1, 0.0])
    seg = _segment(config, 6, 2)
    warm = Teacher(copy.deepcopy(net), 2).follow(seg)
    cool = Teacher(copy.deepcopy(net), 2, temperature=0.25).follow(seg)
    entropy = lambda lp: -(lp.exp() * lp).sum(-1)  # noqa: E731
    assert torch.all(entropy(cool) < entropy(warm))
    assert torch.equal(cool.argmax(-1), warm.argmax(-1))
    assert torch.allclose(cool, torch.log_softmax(warm * 4, dim=-1), atol=1e-5)
    with pytest.raises(ValueError, match="kl_temperature must be a finite number > 0"):
        A3CConfig.from_flat(**SMALL, kl_temperature=0)
