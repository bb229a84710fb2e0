"""Figures without pyplot, PNGs and GIFs written atomically, GIFs subsampled to a frame budget."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from bimgame.util.images import save_png, subplots, write_gif

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _frames(count: int, size: int = 8) -> list[np.ndarray]:
    """``count`` distinct RGB frames (PIL merges identical consecutive GIF frames)."""
    return [np.full((size, size, 3), (7 * i) % 256, dtype=np.uint8) for i in range(count)]


def test_subplots_and_save_png_never_import_pyplot(tmp_path):
    code = ("import bimgame.util.images as m; f,a=m.subplots(); a.plot([0,1],[1,0]); m.save_png(f,'x.png',dpi=50); "
            "import sys; print('matplotlib.pyplot' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
    assert (tmp_path / "x.png").read_bytes().startswith(PNG_MAGIC)


def test_subplots_passes_figure_and_axes_options():
    figure, axes = subplots(2, 3, figsize=(6, 4), dpi=40, sharex=True)
    assert axes.shape == (2, 3)
    assert tuple(figure.get_size_inches()) == (6, 4) and figure.dpi == 40
    single_figure, single = subplots()
    assert single.figure is single_figure
    _, grid = subplots(1, 2, squeeze=False)
    assert grid.shape == (1, 2)


def test_save_png_writes_a_valid_png_atomically(tmp_path):
    figure, axes = subplots(figsize=(2, 1))
    axes.plot([0, 1, 2], [0, 1, 0])
    path = save_png(figure, tmp_path / "out" / "plot.png", dpi=50)
    assert path == tmp_path / "out" / "plot.png"
    assert path.read_bytes().startswith(PNG_MAGIC)
    with Image.open(path) as image:
        image.verify()
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size == (100, 50)
    assert [p.name for p in path.parent.iterdir()] == ["plot.png"]  # no temporary file left
    # overwriting replaces the file, again without leftovers
    save_png(figure, path, dpi=100)
    with Image.open(path) as image:
        assert image.size == (200, 100)
    assert [p.name for p in path.parent.iterdir()] == ["plot.png"]


def test_save_png_closes_a_pyplot_figure(tmp_path):
    code = ("import matplotlib; matplotlib.use('Agg'); import matplotlib.pyplot as plt; "
            "from bimgame.util.images import save_png; f = plt.figure(); save_png(f, 'p.png', dpi=20); "
            "print(plt.get_fignums())")
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_write_gif_keeps_every_frame_under_the_budget(tmp_path):
    path = write_gif(_frames(5), tmp_path / "anim.gif", fps=10)
    with Image.open(path) as image:
        assert image.format == "GIF"
        assert image.n_frames == 5
        assert image.size == (8, 8)
        assert image.info["duration"] == 100
    assert [p.name for p in tmp_path.iterdir()] == ["anim.gif"]


@pytest.mark.parametrize("count, max_frames, expected", [(25, 10, 9), (20, 10, 10), (30, 7, 6), (3, 1, 1)])
def test_write_gif_subsamples_to_at_most_max_frames(tmp_path, count, max_frames, expected):
    path = write_gif(_frames(count), tmp_path / "long.gif", fps=20, max_frames=max_frames)
    with Image.open(path) as image:
        assert image.n_frames == expected
        assert image.n_frames <= max_frames
        stride = -(-count // max_frames)
        assert image.info["duration"] == round(1000 * stride / 20)  # playback time is kept


def test_write_gif_keeps_the_frame_content(tmp_path):
    frames = [np.zeros((4, 6, 3), np.uint8), np.full((4, 6, 3), 255, np.uint8)]
    frames[0][..., 0] = 255  # red, then white
    path = write_gif(frames, tmp_path / "two.gif")
    with Image.open(path) as image:
        assert image.size == (6, 4)
        assert image.convert("RGB").getpixel((0, 0)) == (255, 0, 0)
        image.seek(1)
        assert image.convert("RGB").getpixel((0, 0)) == (255, 255, 255)


def test_write_gif_refuses_no_frames(tmp_path):
    with pytest.raises(ValueError, match="no frames"):
        write_gif([], tmp_path / "empty.gif")
    assert not (tmp_path / "empty.gif").exists()
