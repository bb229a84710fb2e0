"""A run's reward settings: a resumed run keeps those in its config.json, and refuses a broken block."""

from __future__ import annotations

import json
import re

import pytest

from bimgame.learn.rewards import RewardSettings, resolve_reward_settings


def _run(tmp_path, reward) -> object:
    config = {"steps": 10} if reward is ... else {"steps": 10, "reward": reward}
    (tmp_path / "config.json").write_text(json.dumps(config))
    return tmp_path


def test_a_new_run_uses_the_given_settings_and_a_resumed_run_its_own(tmp_path):
    given = RewardSettings(geodesic_coef=2.0)
    assert resolve_reward_settings(given, tmp_path / "new", resume=False) == given
    run = _run(tmp_path, {"value_reward": None, "geodesic_coef": 2.0})
    assert resolve_reward_settings(RewardSettings(), run, resume=True) == given
    assert resolve_reward_settings(RewardSettings(), _run(tmp_path, ...), resume=True) == RewardSettings()
    with pytest.raises(ValueError, match="--resume must keep the run's reward"):
        resolve_reward_settings(RewardSettings(geodesic_coef=3.0), _run(tmp_path, {"geodesic_coef": 2.0}),
                                resume=True)


@pytest.mark.parametrize("reward, detail", [
    ([1, 2], r"got \[1, 2\]"),
    ("geodesic", "got 'geodesic'"),
    ({"geodesic": 2.0}, "unknown key 'geodesic'"),
    ({"value_reward": None, "coef": 1, "gamma": 0.9}, "unknown keys 'coef', 'gamma'"),
    ({"value_reward": 5}, "value_reward must be a run directory"),
    ({"geodesic_coef": -1}, "geodesic_coef must be None or a finite number > 0, got -1"),
])
def test_a_bad_reward_block_is_refused_naming_the_file_and_the_allowed_keys(tmp_path, reward, detail):
    """It used to end in a TypeError traceback (RewardSettings(**block))."""
    run = _run(tmp_path, reward)
    with pytest.raises(ValueError) as refused:
        resolve_reward_settings(RewardSettings(), run, resume=True)
    message = str(refused.value)
    assert message.startswith(f"{tmp_path / 'config.json'}: its \"reward\" settings must be a JSON object with "
                              f"the keys value_reward, geodesic_coef")
    assert re.search(detail, message), message
