"""The maze drawing (draw_maze): a valid PNG of a sensible size, the maze where it belongs in the
picture, and the geodesic shading ordered like the geodesic distance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from bimgame.sim.figures import draw_maze
from bimgame.sim.maze import MazeSpec

SPEC = MazeSpec.merl()
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
WALL_GREY = 115  # matplotlib's "0.45"
MARBLE = np.array([0xD0, 0xD4, 0xDC])


@pytest.fixture(scope="module")
def drawings(tmp_path_factory) -> dict[str, np.ndarray]:
    root = tmp_path_factory.mktemp("maze")
    shaded = draw_maze(SPEC, root / "shaded.png")
    plain = draw_maze(SPEC, root / "sub" / "plain.png", geodesic=False)
    assert (shaded, plain) == (root / "shaded.png", root / "sub" / "plain.png")
    images = {}
    for name, path in (("shaded", shaded), ("plain", plain)):
        data = path.read_bytes()
        assert data[:8] == PNG_SIGNATURE, name
        with Image.open(path) as image:
            image.verify()
        with Image.open(path) as image:
            assert image.format == "PNG"
            images[name] = np.asarray(image.convert("RGB")).astype(int)
    # Written atomically: no temporary files left next to them.
    assert sorted(p.name for p in root.rglob("*") if p.is_file()) == ["plain.png", "shaded.png"]
    return images


class _Frame:
    """Pixel coordinates of board points, from the rim's bounding box in the picture (the rim is
    the only large grey object; its outer edge is rim_radius + rim_thickness from the centre)."""

    def __init__(self, pixels: np.ndarray):
        grey = np.all(np.abs(pixels - WALL_GREY) <= 3, axis=-1)
        # Columns/rows crossing the rim hold long runs of grey; antialiased text holds a few.
        cols, rows = np.flatnonzero(grey.sum(0) >= 20), np.flatnonzero(grey.sum(1) >= 20)
        self.cx, self.cy = (cols[0] + cols[-1]) / 2, (rows[0] + rows[-1]) / 2
        extent_mm = (SPEC.rim_radius + SPEC.rim_thickness) * 1e3
        self.px_per_mm = (cols[-1] - cols[0] + 1) / (2 * extent_mm)
        self.px_per_mm_y = (rows[-1] - rows[0] + 1) / (2 * extent_mm)

    def pixel(self, pixels: np.ndarray, x_mm: float, y_mm: float) -> np.ndarray:
        return pixels[int(round(self.cy - y_mm * self.px_per_mm)), int(round(self.cx + x_mm * self.px_per_mm))]


def _colour_count(pixels: np.ndarray) -> int:
    return len(np.unique((pixels[..., 0] << 16) | (pixels[..., 1] << 8) | pixels[..., 2]))


def test_both_drawings_are_sensible_pictures_and_differ(drawings):
    for name, pixels in drawings.items():
        height, width, _ = pixels.shape
        # A 7 x 7 inch figure at 150 dpi, cropped to its content.
        assert 600 <= width <= 1050 and 600 <= height <= 1050, (name, width, height)
        assert _colour_count(pixels) > 20, name  # not a blank image
    shaded, plain = drawings["shaded"], drawings["plain"]
    assert shaded.shape != plain.shape or np.abs(shaded - plain).sum() > 0
    # The shading adds a colour bar beside the maze: the shaded picture is wider than tall, the
    # plain one about square; and it has far more colours.
    assert shaded.shape[1] > 1.1 * shaded.shape[0]
    assert 0.9 < plain.shape[1] / plain.shape[0] < 1.1
    colours = {k: _colour_count(v) for k, v in drawings.items()}
    assert colours["shaded"] > 3 * colours["plain"], colours


@pytest.mark.parametrize("name", ["shaded", "plain"])
def test_the_maze_is_drawn_to_scale_with_the_marble_at_its_start(drawings, name):
    pixels = drawings[name]
    frame = _Frame(pixels)
    assert frame.px_per_mm == pytest.approx(frame.px_per_mm_y, rel=0.01)  # round, not squashed
    # The marble (light grey disc) sits on the outermost channel's centre circle at angle 0.
    marble = np.all(np.abs(pixels - MARBLE) <= 3, axis=-1)
    ys, xs = np.nonzero(marble)
    x_mm, y_mm = (xs.mean() - frame.cx) / frame.px_per_mm, (frame.cy - ys.mean()) / frame.px_per_mm
    start_mm = SPEC.channel_centre_radius(SPEC.outermost_channel) * 1e3
    assert x_mm == pytest.approx(start_mm, abs=0.5) and y_mm == pytest.approx(0.0, abs=0.5)
    # Its area is that of the marble (less its black outline).
    radius_mm = math.sqrt(marble.sum() / math.pi) / frame.px_per_mm
    assert 0.85 * SPEC.marble_radius * 1e3 < radius_mm <= SPEC.marble_radius * 1e3
    # Walls are grey at their mid-radius away from the gates; a gate's middle is open floor.
    for wall in SPEC.walls:
        mid_mm = (wall.inner_radius + wall.outer_radius) / 2 * 1e3
        gate = wall.gates[0]
        solid = gate.angle + math.pi / len(wall.gates)  # halfway to the next gate
        assert np.all(np.abs(frame.pixel(pixels, mid_mm * math.cos(solid), mid_mm * math.sin(solid)) - WALL_GREY) <= 3)
        opening = frame.pixel(pixels, mid_mm * math.cos(gate.angle), mid_mm * math.sin(gate.angle))
        assert np.abs(opening - WALL_GREY).max() > 20, (wall, opening)


# Floor points away from walls and labels, channel 0 to the outermost channel, at least 9 mm of
# geodesic distance apart; ordered by their distance from the centre they would be in another
# order (the shading is the path through the gates, not the radius).
FLOOR_POINTS_MM = [
    (0.0, 10.0),
    (0.0, 28.0),
    (28.0, 0.0),
    (0.0, -48.0),
    (48.0, 0.0),
    (60.0, 35.0),
    (-45.0, 55.0),
    (0.0, 89.0),
    (44.5, 77.1),
]


def test_the_shading_follows_the_geodesic_distance_and_the_plain_floor_is_white(drawings):
    shaded, plain = drawings["shaded"], drawings["plain"]
    frame = _Frame(shaded)
    points = np.array(FLOOR_POINTS_MM) * 1e-3
    distance = SPEC.geodesic_distance(points[:, 0], points[:, 1])
    assert np.diff(np.sort(distance)).min() > 0.008
    radius = np.hypot(points[:, 0], points[:, 1])
    assert not np.array_equal(np.argsort(radius, kind="stable"), np.argsort(distance))
    colours = np.array([frame.pixel(shaded, x, y) for x, y in FLOOR_POINTS_MM])
    # viridis: its green component rises from the smallest to the largest value.
    green = colours[:, 1]
    assert np.array_equal(np.argsort(green), np.argsort(distance)), (distance, colours)
    assert green.min() < 80 and green.max() > 200
    plain_frame = _Frame(plain)
    for x, y in FLOOR_POINTS_MM:
        assert plain_frame.pixel(plain, x, y).tolist() == [255, 255, 255], (x, y)


def test_the_resolution_follows_dpi_and_the_maze_changes_the_picture(tmp_path):
    low = draw_maze(SPEC, tmp_path / "low.png", geodesic=False, dpi=40)
    high = draw_maze(SPEC, tmp_path / "high.png", geodesic=False, dpi=80)
    with Image.open(low) as a, Image.open(high) as b:
        assert b.size[0] == pytest.approx(2 * a.size[0], rel=0.05)
        assert b.size[1] == pytest.approx(2 * a.size[1], rel=0.05)
        low_pixels = np.asarray(a.convert("RGB")).astype(int)
    # Another maze (every gate of the outer wall turned by 20°) gives another picture.
    walls = list(SPEC.walls)
    outer = walls[-1]
    walls[-1] = type(outer)(
        outer.inner_radius, outer.outer_radius, tuple(type(g)(g.angle + math.radians(20), g.width) for g in outer.gates)
    )
    turned = draw_maze(SPEC.replace(walls=tuple(walls)), tmp_path / "turned.png", geodesic=False, dpi=40)
    with Image.open(turned) as c:
        turned_pixels = np.asarray(c.convert("RGB")).astype(int)
    assert turned_pixels.shape == low_pixels.shape
    assert np.abs(turned_pixels - low_pixels).max(axis=-1).astype(bool).sum() > 100


def test_random_mazes_are_drawn_side_by_side_and_differ(tmp_path):
    from bimgame.cli.main import main

    assert main(["maze", "--grid", "2", "--split", "test", "--out", str(tmp_path / "grid.png")]) == 0
    grid = np.asarray(Image.open(tmp_path / "grid.png").convert("L"), dtype=float)
    left, right = grid[:, : grid.shape[1] // 2], grid[:, grid.shape[1] // 2 :]
    assert left.std() > 10 and np.abs(left - right[:, : left.shape[1]]).mean() > 1  # two different mazes
    assert main(["maze", "--number", "5", "--out", str(tmp_path / "five.png")]) == 0
    assert main(["maze", "--number", "6", "--out", str(tmp_path / "six.png")]) == 0
    five = np.asarray(Image.open(tmp_path / "five.png").convert("L"), dtype=float)
    six = np.asarray(Image.open(tmp_path / "six.png").convert("L"), dtype=float)
    assert five.shape == six.shape and np.abs(five - six).mean() > 1
    with pytest.raises(SystemExit, match="exclude each other"):
        main(["maze", "--grid", "2", "--number", "1", "--out", str(tmp_path / "x.png")])
