from __future__ import annotations

import numpy as np
import pytest
import torch

from bimgame.learn.nets import NO_ACTION, NetConfig, build_network, state_obs_scale
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


@pytest.mark.parametrize("config", [NetConfig(), NetConfig(keypoints=True), NetConfig(encoder="mlp", obs_shape=(7,), features=32, hidden=16),
                                    NetConfig(encoder="mlp", obs_shape=(7,), hidden=8, tilt_input=False)])
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
        logits, values, (h, c) = net.step(obs[t], prev_action[t], prev_reward[t],
                                          None if tilt_arg is None else tilt_arg[t], (h * keep, c * keep))
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
    aux = net.aux_inputs(torch.tensor([NO_ACTION, 0, 4]), torch.tensor([0.0, 1.0, -1.0]), None)
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
