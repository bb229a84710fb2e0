from __future__ import annotations

import numpy as np
import pytest
import torch

from bimgame.learn.nets import NO_ACTION, NetConfig, build_network, state_obs_scale
from bimgame.learn.policy_heads import LOG_STD_INIT, Categorical, DiagonalGaussian
from bimgame.sim.maze import MazeSpec


def _inputs(config: NetConfig, steps: int, batch: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    if config.encoder == "conv":
        obs = torch.randint(0, 256, (steps, batch, *config.obs_shape), generator=g, dtype=torch.uint8)
    else:
        obs = torch.randn(steps, batch, *config.obs_shape, generator=g)
    prev_action = torch.randint(-1, 5, (steps, batch), generator=g)
    prev_reward = torch.randn(steps, batch, generator=g)
    tilt = torch.rand(steps, batch, 2, generator=g) * 2 - 1
    starts = torch.rand(steps, batch, generator=g) < 0.2
    return obs, prev_action, prev_reward, tilt, starts


@pytest.mark.parametrize(
    "config",
    [
        NetConfig(),
        NetConfig(keypoints=True),
        NetConfig(encoder="mlp", obs_shape=(7,), features=32, hidden=16),
        NetConfig(encoder="mlp", obs_shape=(7,), hidden=8, tilt_input=False),
    ],
)
def test_unroll_equals_stepping_with_resets(config):
    """The training path (unroll: encoder once over T·B, LSTM over time with resets) computes
    exactly what acting step by step computes."""
    net = build_network(config)
    obs, prev_action, prev_reward, tilt, starts = _inputs(config, 6, 3)
    tilt_arg = tilt if config.tilt_input else None
    state = net.initial_state(3)
    state = (torch.randn_like(state.h), torch.randn_like(state.c))
    logits_u, values_u, final_u = net.unroll(obs, prev_action, prev_reward, tilt_arg, state, starts)
    h, c = state
    for t in range(6):
        keep = (~starts[t]).float().unsqueeze(-1)
        logits, values, (h, c) = net.step(
            obs[t], prev_action[t], prev_reward[t], None if tilt_arg is None else tilt_arg[t], (h * keep, c * keep)
        )
        torch.testing.assert_close(logits, logits_u[t], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(values, values_u[t], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(h, final_u.h, rtol=1e-5, atol=1e-6)
    assert logits_u.shape == (6, 3, 5) and values_u.shape == (6, 3)


def test_paper_network_sizes():
    net = build_network(NetConfig())
    convs = [net.encoder.conv1, net.encoder.conv2]
    assert [(c.out_channels, c.kernel_size, c.stride) for c in convs] == [(16, (8, 8), (4, 4)), (32, (4, 4), (2, 2))]
    assert net.encoder.fc[0].in_features == 32 * 9 * 9 and net.encoder.fc[0].out_features == 256
    assert net.lstm.hidden_size == 256
    # LSTM input: features + one-hot previous action (5) + previous reward + tilt (2)
    assert net.lstm.input_size == 256 + 5 + 1 + 2
    assert build_network(NetConfig(tilt_input=False)).lstm.input_size == 256 + 6


def test_previous_action_one_hot_and_no_action():
    net = build_network(NetConfig(encoder="mlp", obs_shape=(7,), tilt_input=False))
    aux = net.side_inputs(torch.tensor([NO_ACTION, 0, 4]), torch.tensor([0.0, 1.0, -1.0]), None)
    expected = torch.tensor([[0, 0, 0, 0, 0, 0.0], [1, 0, 0, 0, 0, 1.0], [0, 0, 0, 0, 1, -1.0]])
    torch.testing.assert_close(aux, expected)


def test_initial_policy_is_near_uniform():
    net = build_network(NetConfig())
    obs, prev_action, prev_reward, tilt, _ = _inputs(net.config, 1, 8)
    logits, _, _ = net.step(obs[0], prev_action[0], prev_reward[0], tilt[0], net.initial_state(8))
    probs = torch.softmax(logits, -1)
    assert torch.allclose(probs, torch.full_like(probs, 0.2), atol=0.02)


def test_mlp_scale_and_errors():
    spec = MazeSpec.merl()
    scale = state_obs_scale(spec)
    assert scale.shape == (7,) and np.all(scale > 0)
    net = build_network(NetConfig(encoder="mlp", obs_shape=(7,)), obs_scale=scale)
    torch.testing.assert_close(net.encoder.scale, torch.as_tensor(scale))
    with pytest.raises(ValueError, match="obs_scale must be"):
        build_network(NetConfig(encoder="mlp", obs_shape=(7,)), obs_scale=np.ones(3))
    with pytest.raises(ValueError, match="unknown encoder 'rnn'; allowed: conv, mlp"):
        NetConfig(encoder="rnn")
    with pytest.raises(ValueError, match="mlp encoder needs obs_shape"):
        NetConfig(encoder="mlp", obs_shape=(1, 84, 84))
    with pytest.raises(ValueError, match="hidden must be >= 1"):
        NetConfig(hidden=0)
    with pytest.raises(ValueError, match="unknown network settings"):
        NetConfig.from_dict({"encoder": "conv", "layers": 3})
    with pytest.raises(ValueError, match="takes the board tilt"):
        net.step(torch.zeros(1, 7), torch.tensor([0]), torch.tensor([0.0]), None, net.initial_state(1))


def test_pixel_features_vary_with_the_marble():
    """The conv encoder's initial features must change with the marble's position on the scale of
    the LSTM's other inputs (one-hot action, tilt: order 1), or the LSTM cannot tell states apart.
    With PyTorch's default init and no normalisation the per-unit spread across positions was
    0.0016 (0.007 with background subtraction)."""
    from bimgame.learn.nets import maze_background
    from bimgame.sim.render import MazeRenderer

    spec = MazeSpec.merl()
    rng = np.random.default_rng(0)
    radius = rng.uniform(0.02, spec.rim_radius * 0.9, 64)
    angle = rng.uniform(-np.pi, np.pi, 64)
    xy = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)[:, None]
    frames = torch.as_tensor(MazeRenderer(spec, 84).gray(xy)[:, None])
    for subtract, min_spread in ((False, 0.03), (True, 0.3)):
        config = NetConfig(subtract_background=subtract)
        net = build_network(config, background=maze_background(spec) if subtract else None)
        with torch.no_grad():
            features = net.encoder(frames)
        spread = features.std(0).mean()
        assert spread > min_spread, (subtract, float(spread))
    with pytest.raises(ValueError, match="subtract_background needs the empty-maze frame"):
        build_network(NetConfig(subtract_background=True))


# ------------------------------------------------------------------ privileged heads, bf16
def _privileged_net(**overrides) -> "RecurrentActorCritic":  # noqa: F821
    from bimgame.learn.common import NetworkSettings

    settings = NetworkSettings(
        obs="pixels", hidden=32, features=32, **{"aux_heads": False, "asymmetric_critic": False, **overrides}
    )
    return settings.build_policy(seed=0)


def _privileged_inputs(steps: int, batch: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    scale = torch.as_tensor(state_obs_scale(MazeSpec.merl()))
    return (torch.rand(steps, batch, 7, generator=g) * 2 - 1) * scale


def test_aux_loss_is_the_error_of_both_heads_in_scaled_units():
    net = _privileged_net(aux_heads=True)
    config = net.config
    obs, prev_action, prev_reward, tilt, starts = _inputs(config, 4, 3)
    privileged = _privileged_inputs(4, 3)
    out = net.unroll_features(obs, prev_action, prev_reward, tilt, net.initial_state(3), starts)
    loss, parts = net.aux_loss(out.features, out.hidden, privileged)
    target = privileged / net.privileged_scale
    frame = (net.aux_frame(out.features) - target[..., [0, 1, 6]]).pow(2).mean()
    memory = (net.aux_memory(out.hidden) - target).pow(2).mean()
    torch.testing.assert_close(loss, frame + memory)
    assert parts == pytest.approx({"aux_frame": frame.item(), "aux_memory": memory.item()})
    # A mask counts only the selected steps.
    mask = torch.zeros(4, 3, dtype=torch.bool)
    mask[1, 2] = True
    masked, _ = net.aux_loss(out.features, out.hidden, privileged, mask)
    expected = (net.aux_frame(out.features[1, 2]) - target[1, 2, [0, 1, 6]]).pow(2).mean() + (
        net.aux_memory(out.hidden[1, 2]) - target[1, 2]
    ).pow(2).mean()
    torch.testing.assert_close(masked, expected)


def test_aux_heads_learn_and_leave_the_policy_head_alone():
    """Gradient steps on the auxiliary loss alone lower it and never touch π's head."""
    net = _privileged_net(aux_heads=True)
    obs, prev_action, prev_reward, tilt, starts = _inputs(net.config, 5, 4)
    privileged = _privileged_inputs(5, 4)
    policy_before = net.policy.weight.detach().clone()
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-2)
    losses = []
    for _ in range(30):
        out = net.unroll_features(obs, prev_action, prev_reward, tilt, net.initial_state(4), starts)
        loss, _ = net.aux_loss(out.features, out.hidden, privileged)
        optimizer.zero_grad()
        loss.backward()
        assert net.policy.weight.grad is None or not net.policy.weight.grad.any()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]
    assert torch.equal(net.policy.weight, policy_before)


def test_network_without_aux_heads_refuses_the_aux_loss():
    net = _privileged_net()
    with pytest.raises(ValueError, match="no auxiliary heads"):
        net.aux_loss(torch.zeros(1, 32), torch.zeros(1, 32), torch.zeros(1, 7))


def test_asymmetric_critic_reads_the_state_and_only_the_value():
    net = _privileged_net(asymmetric_critic=True)
    obs, prev_action, prev_reward, tilt, starts = _inputs(net.config, 3, 2)
    a, b = _privileged_inputs(3, 2, seed=1), _privileged_inputs(3, 2, seed=2)
    state = net.initial_state(2)
    logits_a, values_a, _ = net.unroll(obs, prev_action, prev_reward, tilt, state, starts, privileged=a)
    logits_b, values_b, _ = net.unroll(obs, prev_action, prev_reward, tilt, state, starts, privileged=b)
    torch.testing.assert_close(logits_a, logits_b)  # the policy does not see the privileged state
    assert not torch.allclose(values_a, values_b)
    _, values_none, _ = net.unroll(obs, prev_action, prev_reward, tilt, state, starts)
    assert torch.isnan(values_none).all()  # acting without the state: no value, and no silent one
    critic = {id(p) for p in net.critic_parameters()}
    assert {id(p) for p in net.value.parameters()} | {id(p) for p in net.critic_state.parameters()} == critic


def test_privileged_settings_need_the_state_size():
    with pytest.raises(ValueError, match="privileged_size"):
        NetConfig(aux_heads=True)
    with pytest.raises(ValueError, match="privileged_size"):
        NetConfig(asymmetric_critic=True)
    with pytest.raises(ValueError, match="5·n \\+ 2"):
        NetConfig(privileged_size=6)
    with pytest.raises(ValueError, match="privileged_scale"):
        build_network(NetConfig(privileged_size=7, aux_heads=True))
    with pytest.raises(ValueError, match="precision"):
        NetConfig(precision="fp16")


def test_old_checkpoints_load_into_a_network_without_privileged_parts():
    """The privileged scale is not stored: weights saved before it existed still load strictly."""
    net = build_network(NetConfig())
    assert "privileged_scale" not in net.state_dict()


def test_bf16_and_fp32_act_alike_on_real_frames():
    """bfloat16 autocast of the encoder changes a trained-scale policy's probabilities by little, and
    its greedy actions only where two actions are nearly tied."""
    from bimgame.envs.vector import BallInMazeVectorEnv

    env = BallInMazeVectorEnv(64, task="FULL", obs_mode="pixels")
    obs, info = env.reset(seed=0)
    fp32 = build_network(NetConfig(), seed=3)
    with torch.no_grad():
        fp32.policy.weight.normal_(0, 0.3, generator=torch.Generator().manual_seed(0))  # decisive logits
    bf16 = build_network(NetConfig(precision="bf16"), seed=3)
    bf16.load_state_dict(fp32.state_dict())
    prev_action = torch.full((64,), NO_ACTION)
    tilt = torch.as_tensor(info["tilt"], dtype=torch.float32) / env.maze.max_tilt
    with torch.no_grad():
        logits32, values32, _ = fp32.step(
            torch.as_tensor(obs), prev_action, torch.zeros(64), tilt, fp32.initial_state(64)
        )
        logits16, values16, _ = bf16.step(
            torch.as_tensor(obs), prev_action, torch.zeros(64), tilt, bf16.initial_state(64)
        )
    p32, p16 = torch.softmax(logits32, -1), torch.softmax(logits16, -1)
    assert (p32 - p16).abs().max() < 0.02
    torch.testing.assert_close(values16, values32, atol=0.05, rtol=0.05)
    top2 = p32.topk(2, dim=-1).values
    decisive = (top2[:, 0] - top2[:, 1]) > 0.04
    assert decisive.sum() > 10
    assert torch.equal(logits32.argmax(-1)[decisive], logits16.argmax(-1)[decisive])
    assert logits16.dtype == torch.float32


# ------------------------------------------------------------------------------ continuous actions
#: A small discrete network with every optional part: its weights' names, shapes and, for seed 11,
#: sums — as built before continuous actions existed (the same parameters from the same draws, so
#: that stored checkpoints and seeds keep their meaning).
_DISCRETE = NetConfig(
    encoder="mlp", obs_shape=(7,), features=16, hidden=8, privileged_size=7, aux_heads=True, asymmetric_critic=True
)
_DISCRETE_SHAPES = [
    ("encoder.scale", (7,)),
    ("encoder.net.0.weight", (16, 7)),
    ("encoder.net.0.bias", (16,)),
    ("encoder.net.2.weight", (16, 16)),
    ("encoder.net.2.bias", (16,)),
    ("lstm.weight_ih", (32, 24)),
    ("lstm.weight_hh", (32, 8)),
    ("lstm.bias_ih", (32,)),
    ("lstm.bias_hh", (32,)),
    ("policy.weight", (5, 8)),
    ("policy.bias", (5,)),
    ("critic_state.0.weight", (128, 7)),
    ("critic_state.0.bias", (128,)),
    ("critic_state.2.weight", (128, 128)),
    ("critic_state.2.bias", (128,)),
    ("value.weight", (1, 136)),
    ("value.bias", (1,)),
    ("aux_frame.weight", (3, 16)),
    ("aux_frame.bias", (3,)),
    ("aux_memory.weight", (7, 8)),
    ("aux_memory.bias", (7,)),
]
_DISCRETE_SUMS = {
    "encoder.net.0.weight": 0.898434,
    "encoder.net.0.bias": 0.927611,
    "encoder.net.2.weight": -0.550163,
    "encoder.net.2.bias": -0.179427,
    "lstm.weight_ih": -3.502347,
    "lstm.weight_hh": -1.332567,
    "policy.weight": -0.077163,
    "critic_state.0.weight": 2.720631,
    "critic_state.0.bias": 1.523801,
    "critic_state.2.weight": -5.604327,
    "critic_state.2.bias": 1.5e-05,
    "value.weight": 0.544885,
    "aux_frame.weight": -0.181156,
    "aux_frame.bias": -0.034993,
    "aux_memory.weight": 0.879648,
    "aux_memory.bias": -0.172429,
}


def _continuous(**overrides) -> "RecurrentActorCritic":  # noqa: F821
    config = NetConfig(encoder="mlp", obs_shape=(7,), features=16, hidden=8, action_type="continuous", **overrides)
    return build_network(config, obs_scale=state_obs_scale(MazeSpec.merl()), seed=1)


def test_discrete_networks_keep_their_weights_names_shapes_and_initial_values():
    net = build_network(_DISCRETE, privileged_scale=state_obs_scale(MazeSpec.merl()), seed=11)
    assert [(k, tuple(v.shape)) for k, v in net.state_dict().items()] == _DISCRETE_SHAPES
    assert net.log_std is None and isinstance(net.distribution(torch.zeros(2, 5)), Categorical)
    sums = {name: float(p.detach().double().sum()) for name, p in net.named_parameters() if p.detach().abs().sum() > 0}
    assert sums == pytest.approx(_DISCRETE_SUMS, abs=2e-6)
    # Stored network settings from before action_type are discrete.
    stored = {k: v for k, v in _DISCRETE.to_dict().items() if k != "action_type"}
    assert NetConfig.from_dict(stored) == _DISCRETE and _DISCRETE.action_type == "discrete"
    with pytest.raises(
        ValueError, match=r"NetConfig\.action_type must be one of \('discrete', 'continuous'\), got 'box'"
    ):
        NetConfig(action_type="box")


def test_a_continuous_network_outputs_gaussian_means_and_a_learned_log_std():
    net = _continuous()
    assert net.policy.out_features == 2 and net.lstm.input_size == 16 + 2 + 1 + 2  # previous action: 2 numbers
    assert net.log_std is not None and torch.equal(net.log_std.detach(), torch.full((2,), LOG_STD_INIT))
    assert "log_std" in net.state_dict() and any(p is net.log_std for p in net.parameters())
    g = torch.Generator().manual_seed(0)
    obs, rewards, tilt = torch.randn(6, 3, 7, generator=g), torch.randn(6, 3, generator=g), torch.zeros(6, 3, 2)
    prev_action = torch.rand(6, 3, 2, generator=g) * 2 - 1
    starts = torch.zeros(6, 3, dtype=torch.bool)
    starts[0] = starts[3, 1] = True
    prev_action[starts] = 0.0  # an episode's first step: no previous action
    means_u, values_u, _ = net.unroll(obs, prev_action, rewards, tilt, net.initial_state(3), starts)
    assert means_u.shape == (6, 3, 2) and values_u.shape == (6, 3)
    state = net.initial_state(3)
    for t in range(6):  # stepping computes what unrolling computes
        keep = (~starts[t]).float().unsqueeze(-1)
        means, values, state = net.step(obs[t], prev_action[t], rewards[t], tilt[t], (state.h * keep, state.c * keep))
        torch.testing.assert_close(means, means_u[t], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(values, values_u[t], rtol=1e-5, atol=1e-6)
    policy = net.distribution(means_u)
    assert isinstance(policy, DiagonalGaussian) and torch.equal(policy.greedy(), means_u)
    assert means_u.abs().max() < 0.2  # small initial means: exploration comes from the log std
    with pytest.raises(ValueError, match=r"previous actions of shape \(…, 2\)"):
        net.step(obs[0], torch.zeros(3, dtype=torch.long), torch.zeros(3), torch.zeros(3, 2), net.initial_state(3))


def test_maze_input_starts_silent_and_learns():
    """A network reading a maze encoding through its own zero-initialised weights is, untrained, the
    network without the encoding from the same seed (same weights, same outputs whatever the maze),
    and the encoding's weights get gradients."""
    plain = build_network(NetConfig(encoder="mlp", obs_shape=(7,), features=32, hidden=16), seed=3)
    mazed = build_network(NetConfig(encoder="mlp", obs_shape=(7 + 128,), features=32, hidden=16, maze_size=128), seed=3)
    plain_state, mazed_state = plain.state_dict(), mazed.state_dict()
    assert set(mazed_state) == set(plain_state) | {"encoder.maze_weight"}
    for name, value in plain_state.items():
        if name != "encoder.scale":
            assert torch.equal(mazed_state[name], value), name
    assert torch.count_nonzero(mazed.encoder.maze_weight) == 0
    obs, prev_action, prev_reward, tilt, starts = _inputs(plain.config, 4, 2)
    encoding = (torch.rand(4, 2, 128) < 0.2).float()
    logits_p, values_p, _ = plain.unroll(obs, prev_action, prev_reward, tilt, plain.initial_state(2), starts)
    logits_m, values_m, _ = mazed.unroll(
        torch.cat([obs, encoding], -1), prev_action, prev_reward, tilt, mazed.initial_state(2), starts
    )
    torch.testing.assert_close(logits_m, logits_p)
    torch.testing.assert_close(values_m, values_p)
    (logits_m.sum() + values_m.sum()).backward()
    assert torch.count_nonzero(mazed.encoder.maze_weight.grad) > 0


def test_maze_size_is_checked():
    with pytest.raises(ValueError, match="maze_size needs the mlp encoder"):
        NetConfig(maze_size=128)
    with pytest.raises(ValueError, match="needs the mlp encoder and < 7 values, got 7"):
        NetConfig(encoder="mlp", obs_shape=(7,), maze_size=7)
    # Networks stored before maze_size read a 135-value observation as plain inputs: they still build.
    assert build_network(NetConfig(encoder="mlp", obs_shape=(135,), features=8, hidden=8)).encoder.maze_weight is None
