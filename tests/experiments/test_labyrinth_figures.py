"""Where labyrinth episodes ended (bimgame.experiments.labyrinth_figures): episodes grouped by how
and where on the path they ended, the figure written, and summaries that are not labyrinth scores
refused."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.experiments.labyrinth_figures import CLUSTER_M, end_clusters, plot_episode_ends
from bimgame.sim.labyrinth import LabyrinthSpec


def _summary(arcs_m, ended, layout="hard"):
    length = LabyrinthSpec.layout(layout).path.length
    return {"layout": layout, "task": f"LABYRINTH-{layout.upper()}", "policy": "test",
            "progress_fractions": [a / length for a in arcs_m], "ended": ended}


def test_ends_within_a_centimetre_of_path_and_ended_alike_share_a_cluster():
    length = LabyrinthSpec.layout("hard").path.length
    arcs = [0.172, 0.174, 0.176, 0.176, 0.452, 0.452, length]
    ended = ["fall", "fall", "fall", "time", "fall", "fall", "goal"]
    clusters = end_clusters(_summary(arcs, ended))
    assert [(how, count) for how, _, count in clusters] == [("fall", 3), ("fall", 2), ("time", 1), ("goal", 1)]
    assert clusters[0][1] == pytest.approx(np.mean(arcs[:3]))
    assert clusters[3][1] == pytest.approx(length)
    assert all(0.0 <= arc <= length for _, arc, _ in clusters)
    apart = end_clusters(_summary([0.3, 0.3 + 1.5 * CLUSTER_M], ["fall", "fall"]))
    assert [count for _, _, count in apart] == [1, 1]


def test_holes_and_the_path_left_are_told_apart_and_older_falls_still_drawn(tmp_path):
    clusters = end_clusters(_summary([0.2, 0.2, 0.2, 0.6], ["hole", "hole", "off_path", "goal"]))
    assert [(how, count) for how, _, count in clusters] == [("hole", 2), ("off_path", 1), ("goal", 1)]
    out = plot_episode_ends(_summary([0.2, 0.2, 0.3], ["hole", "off_path", "fall"]), tmp_path / "ends.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_figure_is_written_atomically_as_png(tmp_path):
    out = plot_episode_ends(_summary([0.05, 0.4, 0.41], ["fall", "fall", "time"]), tmp_path / "sub" / "ends.png")
    assert out == tmp_path / "sub" / "ends.png" and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in out.parent.iterdir()] == ["ends.png"]  # no temporary file left


@pytest.mark.parametrize(
    ("summary", "message"),
    [
        ({"task": "STG1", "returns": [1.0]}, "not a labyrinth score summary: it lacks layout, progress_fractions"),
        (_summary([0.1], ["crashed"]), "summary's ended must name one of hole, off_path, fall, time, goal per episode"),
        (_summary([0.1, 0.2], ["fall"]), "summary's ended must name one of hole, off_path, fall, time, goal per episode \\(2\\)"),
        ({**_summary([0.1], ["fall"]), "layout": "spiral"}, "spiral"),
    ],
)
def test_summaries_that_are_not_labyrinth_scores_are_refused(tmp_path, summary, message):
    with pytest.raises(ValueError, match=message):
        plot_episode_ends(summary, tmp_path / "ends.png")
    assert not (tmp_path / "ends.png").exists()
