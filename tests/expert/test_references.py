"""The normalised score's references: stored with the package and written into the expert datasets,
so that Minari's own normalisation agrees with bimgame's."""

from __future__ import annotations

import minari
import numpy as np
import pytest

from bimgame.expert.datasets import generate_dataset, load_dataset
from bimgame.expert.mpc import MPCConfig
from bimgame.expert.references import normalised_score, references_for


def test_normalised_score_maps_the_references_to_0_and_100():
    low, high = references_for("STG1")
    assert normalised_score("stg1", low) == pytest.approx(0.0)
    assert normalised_score("STG1", high) == pytest.approx(100.0)
    assert normalised_score("STG1", (low + high) / 2) == pytest.approx(50.0)


def test_datasets_carry_the_references_for_minaris_normalisation(tmp_path):
    out = generate_dataset(tmp_path / "data", task="STG1", episodes=2, seed=0,
                           config=MPCConfig(n_samples=4, horizon=8), workers=1, progress=False)
    dataset = load_dataset(out if out is not None else tmp_path / "data")
    returns = np.array([0.5, 1.0])
    # Minari's normalised score is a fraction; bimgame's is a percentage, as in D4RL's tables.
    np.testing.assert_allclose(100 * minari.get_normalized_score(dataset, returns),
                               [normalised_score("STG1", r) for r in returns])
