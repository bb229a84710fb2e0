"""Tests of the labyrinth's numpy raster (bimgame.sim.labyrinth_render): the marble drawn where it
is, holes and walls where the layout has them, the marble-centred crop, the cached background."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.sim.labyrinth import LabyrinthSpec
from bimgame.sim.labyrinth_render import GRAY, LabyrinthRaster, background, board_grid, sheet_grid


@pytest.fixture(scope="module")
def hard() -> LabyrinthSpec:
    return LabyrinthSpec.layout("hard")


def marble_centroid(frame: np.ndarray, bg: np.ndarray) -> np.ndarray:
    """(col, row) centroid of what the marble added to the background."""
    weight = frame.astype(np.float64) - bg
    weight[weight < 0] = 0
    rows, cols = np.indices(frame.shape)
    return np.array([(weight * cols).sum(), (weight * rows).sum()]) / weight.sum()


def test_grids_map_board_points_north_up(hard):
    grid = board_grid(hard, 84)
    top_left, centre = grid.to_pixel(np.array([[grid.left, grid.top], [0.0, 0.0]]))
    assert top_left == pytest.approx([-0.5, -0.5]) and centre == pytest.approx([41.5, 41.5])
    col, row = grid.to_pixel(np.array([0.01, 0.02]))
    assert col > 41.5 and row < 41.5  # +x is right, +y is up
    sheet = sheet_grid(hard)
    assert sheet.pixel == 1e-3 and sheet.width == 291 + 66 and sheet.height == 246 + 66


@pytest.mark.parametrize("xy", [(0.0123, 0.0456), (-0.1, -0.08), (0.0607, 0.1004)])
@pytest.mark.parametrize("size", [84, 128])
def test_marble_is_drawn_where_it_is(hard, xy, size):
    raster = LabyrinthRaster(hard, board_grid(hard, size))
    frame = raster.gray(np.array(xy))
    assert frame.shape == (size, size) and frame.dtype == np.uint8
    assert frame.max() == GRAY["marble"][0]  # the marble is the only pure white
    assert raster.background.max() < GRAY["marble"][0]
    expected = raster.grid.to_pixel(np.array(xy))
    assert np.abs(marble_centroid(frame, raster.background) - expected).max() < 0.5


def test_holes_are_black_and_walls_light_where_the_layout_has_them(hard):
    sheet = LabyrinthRaster(hard, sheet_grid(hard), path_width=0.0)
    bg = sheet.background
    for hole in hard.holes:
        col, row = np.rint(sheet.grid.to_pixel(np.array(hole))).astype(int)
        assert bg[row, col] == GRAY["hole"][0]
    for x0, y0, x1, y1 in hard.walls:
        col, row = np.rint(sheet.grid.to_pixel(np.array([(x0 + x1) / 2, (y0 + y1) / 2]))).astype(int)
        assert bg[row, col] == GRAY["wall"][0]
    # a floor pixel far from everything, the rim and the outside
    assert bg[0, 0] == GRAY["outside"][0]
    col, row = np.rint(sheet.grid.to_pixel(np.array([0.0, hard.board_size[1] / 2 + 0.003]))).astype(int)
    assert bg[row, col] == GRAY["wall"][0]
    # the small view keeps them: hole centres dark, wall centres lighter than the floor
    small = LabyrinthRaster(hard, board_grid(hard, 84), path_width=0.0).background
    grid = board_grid(hard, 84)
    holes = np.rint(grid.to_pixel(np.array(hard.holes))).astype(int)
    assert small[holes[:, 1], holes[:, 0]].max() < 40
    walls = np.array(hard.walls)
    long = walls[np.maximum(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]) > 0.015]
    centres = np.rint(grid.to_pixel((long[:, :2] + long[:, 2:]) / 2)).astype(int)
    assert small[centres[:, 1], centres[:, 0]].min() > GRAY["floor"][0] + 20


def test_path_is_printed_darker_than_the_floor(hard):
    raster = LabyrinthRaster(hard, sheet_grid(hard))
    a, b = np.array(hard.waypoints[0]), np.array(hard.waypoints[1])
    col, row = np.rint(raster.grid.to_pixel((a + b) / 2)).astype(int)
    assert raster.background[row, col] == GRAY["path"][0]


def test_crop_is_centred_on_the_marble_and_padded_outside_the_board(hard):
    raster = LabyrinthRaster(hard, sheet_grid(hard), path_width=0.0)
    # clean floor around each (path points: no hole, wall or path edge under the marble's disc biases it)
    for k in (0, 5, 8, 30):
        xy = np.array(hard.waypoints[k]) + (0.0003, -0.0004)
        crop = raster.crop(np.array(xy))
        assert crop.shape == (64, 64) and crop[32, 32] == GRAY["marble"][0]
        col, row = raster.grid.to_pixel(np.array(xy))
        expected = np.array([col - round(col) + 32, row - round(row) + 32])
        plain = raster.background[round(row) - 32 : round(row) + 32, round(col) - 32 : round(col) + 32]
        assert np.abs(marble_centroid(crop, plain) - expected).max() < 0.3
    corner = raster.crop(np.array(hard.waypoints[8]))  # (9, 195) mm: the window reaches past the left rim
    assert corner[32, 0] == GRAY["outside"][0]
    far = raster.crop(np.array((1.0, 1.0)))  # off the sheet entirely: the marble on the outside
    assert (far[:20] == GRAY["outside"][0]).all() and far[32, 32] == GRAY["marble"][0]
    with pytest.raises(ValueError, match="finite"):
        raster.crop(np.array((np.nan, 0.0)))


def test_background_is_cached_and_read_only(hard):
    grid = board_grid(hard, 84)
    assert background(hard, grid) is background(hard, grid)
    assert not background(hard, grid).flags.writeable
    frame = LabyrinthRaster(hard, grid).gray(np.zeros(2))
    assert frame.flags.writeable
    rgb = LabyrinthRaster(hard, grid).rgb(np.zeros(2))
    assert rgb.shape == (84, 84, 3) and rgb.dtype == np.uint8
    with pytest.raises(ValueError, match="path_width"):
        LabyrinthRaster(hard, grid, path_width=-1.0)
