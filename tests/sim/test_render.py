"""Tests of the numpy raster (bimgame.sim.render): pixel convention, background geometry, marbles.

Lengths in metres, angles in radians. Pixel coordinates are continuous ``(col, row)`` with pixel
``[i, j]``'s centre at ``(j, i)`` (see bimgame.sim.render's module docstring).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bimgame.sim.maze import MazeSpec
from bimgame.sim.render import DEFAULT_RGB_SIZE, FLOOR, GOAL, MARBLE, TILT_ARROW_RGB, WALL, MazeRenderer

SPEC = MazeSpec.merl()
EXTENT = SPEC.rim_radius + SPEC.rim_thickness


@pytest.fixture(scope="module")
def r84() -> MazeRenderer:
    return MazeRenderer(SPEC, 84)


@pytest.fixture(scope="module")
def r400() -> MazeRenderer:
    return MazeRenderer(SPEC, 400)


# ---------------------------------------------------------------------------------- helpers
def random_in_board(rng: np.random.Generator, n: int) -> np.ndarray:
    """n marble positions uniform over the disc the marble's centre can reach (walls ignored)."""
    r_max = SPEC.rim_radius - SPEC.marble_radius
    r = r_max * np.sqrt(rng.uniform(0, 1, n))
    theta = rng.uniform(-np.pi, np.pi, n)
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=-1)


def random_free(rng: np.random.Generator, n: int, margin: float) -> np.ndarray:
    """n marble positions whose disc (plus ``margin``) touches no wall: uniform background."""
    channels = rng.integers(0, SPEC.n_channels, n)
    out = np.empty((n, 2))
    for idx, k in enumerate(channels):
        low, high = SPEC.channel_bounds(int(k))
        r_low = 0.0 if k == 0 else low + SPEC.marble_radius + margin
        r = rng.uniform(r_low, high - SPEC.marble_radius - margin)
        theta = rng.uniform(-np.pi, np.pi)
        out[idx] = r * math.cos(theta), r * math.sin(theta)
    return out


def centroid(weight: np.ndarray) -> np.ndarray:
    """Weighted centroid (col, row) of a (H, W) weight image."""
    rows, cols = np.indices(weight.shape)
    total = weight.sum()
    assert total > 0, "nothing was drawn"
    return np.array([(weight * cols).sum() / total, (weight * rows).sum() / total])


def gray_alpha(img: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Marble coverage recovered from a grayscale frame: (img - bg) / (MARBLE - bg)."""
    bg = background.astype(float)
    return (img.astype(float) - bg) / (MARBLE - bg)


# ---------------------------------------------------------------------------------- convention
def test_pixel_convention(r84: MazeRenderer) -> None:
    s = r84.size
    assert r84.metres_per_pixel == pytest.approx(2 * EXTENT / s)
    corners = np.array([[-EXTENT, EXTENT], [EXTENT, -EXTENT], [0.0, 0.0]])
    np.testing.assert_allclose(
        r84.world_to_pixel(corners), [[-0.5, -0.5], [s - 0.5, s - 0.5], [(s - 1) / 2, (s - 1) / 2]], atol=1e-9
    )
    # North up: +y is towards row 0, +x towards the last column.
    col, row = r84.world_to_pixel(np.array([0.01, 0.02]))
    assert col > (s - 1) / 2 and row < (s - 1) / 2
    # Pixel centres, and the inverse map.
    i, j = 10, 70
    centre = r84.pixel_to_world(np.array([j, i], dtype=float))
    np.testing.assert_allclose(
        centre, [-EXTENT + (j + 0.5) * r84.metres_per_pixel, EXTENT - (i + 0.5) * r84.metres_per_pixel]
    )
    xy = random_in_board(np.random.default_rng(0), 50).reshape(5, 10, 2)
    assert r84.world_to_pixel(xy).shape == (5, 10, 2)
    np.testing.assert_allclose(r84.pixel_to_world(r84.world_to_pixel(xy)), xy, atol=1e-12)
    # Other image sizes.
    np.testing.assert_allclose(r84.world_to_pixel(np.zeros(2), size=480), [239.5, 239.5])


def test_north_up_gates(r400: MazeRenderer) -> None:
    """Wall 2's gate at 90° (+y) is above the centre in the image, the one at 0° (+x) to the right."""
    wall = SPEC.walls[2]
    bg = r400.background
    for angle, expect in ((0.0, FLOOR), (math.pi / 2, FLOOR), (math.pi / 4, WALL)):
        col, row = np.rint(r400.world_to_pixel(wall.mid_radius * np.array([math.cos(angle), math.sin(angle)]))).astype(
            int
        )
        assert bg[row, col] == expect, angle
    col, row = r400.world_to_pixel(wall.mid_radius * np.array([0.0, 1.0]))
    assert row < 200 and abs(col - 199.5) < 1


# ---------------------------------------------------------------------------------- background
def test_wall_and_gate_pixels_merl(r400: MazeRenderer) -> None:
    """MERL wall 1 (gates at 45°, 135°, 225°, 315°): solid at 0°/90°/…, open at the gates."""
    wall = SPEC.walls[1]
    for gate_deg in (45, 135, 225, 315):
        for angle_deg, expect in ((gate_deg, FLOOR), (gate_deg + 45, WALL)):
            angle = math.radians(angle_deg)
            xy = wall.mid_radius * np.array([math.cos(angle), math.sin(angle)])
            col, row = np.rint(r400.world_to_pixel(xy)).astype(int)
            frame = r400.gray(np.zeros((0, 2)))
            assert r400.background[row, col] == expect, (angle_deg, r400.background[row, col])
            assert frame[row, col] == expect


def test_background_matches_geometry_everywhere(r400: MazeRenderer) -> None:
    """Every pixel whose whole footprint lies in one region has exactly that region's level."""
    s = r400.size
    rows, cols = np.indices((s, s))
    xy = r400.pixel_to_world(np.stack([cols, rows], axis=-1).astype(float))
    r = np.hypot(xy[..., 0], xy[..., 1])
    theta = np.arctan2(xy[..., 1], xy[..., 0])
    m = 0.75 * r400.metres_per_pixel  # > half the pixel's diagonal
    expected = np.full((s, s), -1)
    expected[r < SPEC.walls[0].inner_radius - m] = GOAL
    expected[r > SPEC.rim_radius + m] = WALL
    for k in range(1, SPEC.n_channels):
        low, high = SPEC.channel_bounds(k)
        expected[(r > low + m) & (r < high - m)] = FLOOR
    for wall in SPEC.walls:
        ring = (r > wall.inner_radius + m) & (r < wall.outer_radius - m)
        gate_distance = np.full((s, s), np.inf)  # angular distance to the nearest gate edge
        for gate in wall.gates:
            off = np.abs((theta - gate.angle + np.pi) % (2 * np.pi) - np.pi)
            gate_distance = np.minimum(gate_distance, np.abs(off - gate.width / 2))
        clear = ring & (gate_distance * r > m)
        expected[clear] = np.where(wall.in_gate(theta[clear]), FLOOR, WALL)
    known = expected >= 0
    assert known.mean() > 0.8
    bad = known & (r400.background != expected)
    assert not bad.any(), f"{bad.sum()} pixels differ, e.g. at {np.argwhere(bad)[:5].tolist()}"
    # Ambiguous (edge) pixels are antialiased: between the levels they separate.
    assert r400.background.min() >= FLOOR and r400.background.max() <= WALL
    assert len(np.unique(r400.background)) > 10


def test_background_is_read_only_and_unchanged(r84: MazeRenderer) -> None:
    before = r84.background.copy()
    r84.gray(np.array([[0.0, 0.0]]))
    r84.rgb(np.array([[0.0, 0.0]]), size=96)
    np.testing.assert_array_equal(r84.background, before)
    with pytest.raises(ValueError):
        r84.background[0, 0] = 1
    with pytest.raises(ValueError):
        r84.background_rgb(96)[0, 0, 0] = 1


# ---------------------------------------------------------------------------------- marbles
@pytest.mark.parametrize("size", [84, 64, 200])
def test_gray_marble_centroid(size: int) -> None:
    renderer = MazeRenderer(SPEC, size)
    rng = np.random.default_rng(size)
    positions = random_in_board(rng, 200)
    for xy in positions:
        img = renderer.gray(xy[None])
        alpha = gray_alpha(img, renderer.background)
        assert alpha.min() >= -1e-12
        expected = renderer.world_to_pixel(xy)
        np.testing.assert_allclose(centroid(alpha), expected, atol=0.5)
        # Area check: the coverage sums to about the disc's area in pixels.
        assert alpha.sum() == pytest.approx(math.pi * renderer.marble_radius_px**2, rel=0.1)


def test_gray_centroid_is_subpixel_accurate(r84: MazeRenderer) -> None:
    """Sub-pixel motion moves the drawn marble: the centroid tracks to a tenth of a pixel."""
    start = np.array([0.03, -0.02])
    for step in np.linspace(0, 1, 11):
        xy = start + step * r84.metres_per_pixel * np.array([1.0, 0.5])
        alpha = gray_alpha(r84.gray(xy[None]), r84.background)
        np.testing.assert_allclose(centroid(alpha), r84.world_to_pixel(xy), atol=0.1)


@pytest.mark.parametrize("size", [DEFAULT_RGB_SIZE, 320])
def test_rgb_marble_centroid(r84: MazeRenderer, size: int) -> None:
    """RGB marble: intensity-weighted centroid of |img - background| (marble on uniform floor)."""
    rng = np.random.default_rng(size)
    background = r84.background_rgb(size if size != DEFAULT_RGB_SIZE else None).astype(float)
    mpp = 2 * EXTENT / size
    # Keep antialiased wall edges out of the marble's window: R + 0.5 + sqrt(0.5) pixels.
    for xy in random_free(rng, 60, margin=1.25 * mpp):
        img = r84.rgb(xy[None], size=size if size != DEFAULT_RGB_SIZE else None)
        weight = np.abs(img.astype(float) - background).sum(axis=-1)
        np.testing.assert_allclose(centroid(weight), r84.world_to_pixel(xy, size=size), atol=0.5)


def test_rgb_marble_anywhere_inside_board(r84: MazeRenderer) -> None:
    """Marbles overlapping walls are still drawn where they are (changed-pixel centroid)."""
    rng = np.random.default_rng(7)
    background = r84.background_rgb(240)
    for xy in random_in_board(rng, 40):
        img = r84.rgb(xy[None], size=240)
        changed = np.any(img != background, axis=-1).astype(float)
        np.testing.assert_allclose(centroid(changed), r84.world_to_pixel(xy, size=240), atol=0.5)


def test_batch_equals_single_frames(r84: MazeRenderer) -> None:
    rng = np.random.default_rng(3)
    batch, n = 48, 2
    xy = random_in_board(rng, batch * n).reshape(batch, n, 2)
    # Some marbles at or beyond the image border, and one missing (non-finite) marble.
    xy[0, 0] = [EXTENT, EXTENT]
    xy[1, 1] = [-EXTENT - 0.5 * SPEC.marble_radius, 0.01]
    xy[2, 0] = [0.0, -EXTENT + 0.2 * r84.metres_per_pixel]
    xy[3, 1] = [10.0, -10.0]
    xy[4, 0] = [np.nan, 0.0]
    imgs = r84.gray(xy)
    assert imgs.shape == (batch, 84, 84) and imgs.dtype == np.uint8
    for b in range(batch):
        np.testing.assert_array_equal(imgs[b], r84.gray(xy[b]), err_msg=f"frame {b}")
        np.testing.assert_array_equal(imgs[b], r84.gray(xy[b : b + 1])[0], err_msg=f"frame {b}")
    # All windows inside the image (the batch fast path) agree too.
    inner = random_in_board(rng, batch * n).reshape(batch, n, 2)
    imgs = r84.gray(inner)
    for b in range(batch):
        np.testing.assert_array_equal(imgs[b], r84.gray(inner[b]))
    # out= is filled in place and returned; float32 positions give the same frames.
    out = np.full((batch, 84, 84), 7, dtype=np.uint8)
    assert r84.gray(inner, out=out) is out
    np.testing.assert_array_equal(out, imgs)
    single = np.empty((84, 84), dtype=np.uint8)
    assert r84.gray(inner[5], out=single) is single
    np.testing.assert_array_equal(single, imgs[5])
    np.testing.assert_array_equal(
        r84.gray(inner.astype(np.float32)), r84.gray(inner.astype(np.float32).astype(np.float64))
    )


def test_two_marbles_both_drawn(r84: MazeRenderer) -> None:
    a = np.array([SPEC.channel_centre_radius(4), 0.0])
    b = np.array([0.0, 0.0])
    img = r84.gray(np.stack([a, b]))
    for xy in (a, b):
        col, row = np.rint(r84.world_to_pixel(xy)).astype(int)
        assert img[row, col] == MARBLE
    alpha = gray_alpha(img, r84.background)
    assert alpha.sum() == pytest.approx(2 * math.pi * r84.marble_radius_px**2, rel=0.1)
    # Touching marbles (overlapping antialiased edges) are both drawn, composited in order.
    c = b + np.array([2 * SPEC.marble_radius, 0.0])
    img = r84.gray(np.stack([b, c]))
    for xy in (b, c):
        col, row = np.rint(r84.world_to_pixel(xy)).astype(int)
        assert img[row, col] == MARBLE
    rgb = r84.rgb(np.stack([a, b]), size=200)
    for xy in (a, b):
        col, row = np.rint(r84.world_to_pixel(xy, size=200)).astype(int)
        assert np.any(rgb[row, col] != r84.background_rgb(200)[row, col])


@pytest.mark.parametrize(
    "xy",
    [
        (EXTENT, 0.0),
        (EXTENT, EXTENT),
        (-EXTENT, -EXTENT),
        (0.0, EXTENT + SPEC.marble_radius * 0.9),
        (1.0, 1.0),
        (-SPEC.rim_radius + SPEC.marble_radius, 0.0),
    ],
)
def test_marble_at_edge(r84: MazeRenderer, xy: tuple[float, float]) -> None:
    pos = np.array([xy])
    img = r84.gray(pos)
    assert img.shape == (84, 84) and img.dtype == np.uint8
    # Whatever part of the marble lies inside the image is drawn.
    changed = img != r84.background
    col, row = r84.world_to_pixel(pos[0])
    if -0.5 <= col <= 83.5 and -0.5 <= row <= 83.5:
        assert changed.any()
    if abs(xy[0]) > 2 * EXTENT:
        assert not changed.any()
    rgb = r84.rgb(pos, size=120)
    assert rgb.shape == (120, 120, 3) and rgb.dtype == np.uint8
    np.testing.assert_array_equal(r84.gray(pos[None])[0], img)


def test_non_finite_marble_draws_nothing(r84: MazeRenderer) -> None:
    img = r84.gray(np.array([[np.nan, 0.0], [np.inf, 0.01]]))
    np.testing.assert_array_equal(img, r84.background)
    np.testing.assert_array_equal(r84.rgb(np.array([[np.nan, np.nan]]), size=96), r84.background_rgb(96))


# ---------------------------------------------------------------------------------- shapes
def test_shapes_and_dtypes(r84: MazeRenderer) -> None:
    one = np.array([[0.01, 0.02]])
    assert r84.gray(one).shape == (84, 84)
    assert r84.gray(one).dtype == np.uint8
    assert r84.gray(np.zeros((5, 3, 2))).shape == (5, 84, 84)
    assert r84.gray(np.zeros((0, 1, 2))).shape == (0, 84, 84)
    np.testing.assert_array_equal(r84.gray(np.zeros((0, 2))), r84.background)
    assert r84.background.shape == (84, 84) and r84.background.dtype == np.uint8
    frame = r84.rgb(one)
    assert frame.shape == (DEFAULT_RGB_SIZE, DEFAULT_RGB_SIZE, 3) and frame.dtype == np.uint8
    assert r84.rgb(one, size=100).shape == (100, 100, 3)
    assert r84.background_rgb(100) is r84.background_rgb(100)  # cached per size
    # A non-contiguous view (as sliced from board-frame states) is accepted.
    states = np.zeros((4, 2, 3))
    assert r84.gray(states[..., :2]).shape == (4, 84, 84)


@pytest.mark.parametrize("shape", [(2,), (1, 3), (4, 1, 3), (2, 2, 2, 2), ()])
def test_bad_marble_shape_raises(r84: MazeRenderer, shape: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match=r"\(n_marbles, 2\) or \(B, n_marbles, 2\)"):
        r84.gray(np.zeros(shape))


def test_bad_rgb_input_raises(r84: MazeRenderer) -> None:
    with pytest.raises(ValueError, match=r"\(n_marbles, 2\)"):
        r84.rgb(np.zeros((3, 1, 2)))
    with pytest.raises(ValueError, match="size"):
        r84.rgb(np.zeros((1, 2)), size=0)
    with pytest.raises(ValueError, match="tilt"):
        r84.rgb(np.zeros((1, 2)), size=100, tilt=(0.1, 0.2, 0.3))


def test_bad_out_raises(r84: MazeRenderer) -> None:
    with pytest.raises(ValueError, match=r"shape \(2, 84, 84\)"):
        r84.gray(np.zeros((2, 1, 2)), out=np.empty((3, 84, 84), dtype=np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        r84.gray(np.zeros((1, 2)), out=np.empty((84, 84), dtype=np.float32))


def test_bad_constructor_args() -> None:
    with pytest.raises(ValueError, match="size"):
        MazeRenderer(SPEC, 0)
    with pytest.raises(TypeError, match="MazeSpec"):
        MazeRenderer("merl")  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------- tilt gauge
def _red_centroid(img: np.ndarray) -> np.ndarray:
    red = np.all(np.abs(img.astype(int) - np.array(TILT_ARROW_RGB)) < 30, axis=-1)
    return centroid(red.astype(float))


def test_tilt_indicator(r84: MazeRenderer) -> None:
    size = 240
    xy = np.array([[0.02, 0.03]])
    plain = r84.rgb(xy, size=size)
    t = SPEC.max_tilt
    tilted = r84.rgb(xy, size=size, tilt=(0.0, t))
    changed = np.any(tilted != plain, axis=-1)
    assert changed.any()
    # Only the corner outside the board's rim is touched.
    rows, cols = np.nonzero(changed)
    radius_px = np.hypot(cols - (size - 1) / 2, rows - (size - 1) / 2)
    assert radius_px.min() * (2 * EXTENT / size) > EXTENT
    # Tilt about +y lowers the +x edge: the arrow points right; about +x it points down (-y).
    right = _red_centroid(r84.rgb(xy, size=size, tilt=(0.0, t)))
    left = _red_centroid(r84.rgb(xy, size=size, tilt=np.array([0.0, -t])))
    down = _red_centroid(r84.rgb(xy, size=size, tilt=(t, 0.0)))
    up = _red_centroid(r84.rgb(xy, size=size, tilt=(-t, 0.0)))
    assert right[0] > left[0] + 5 and abs(right[1] - left[1]) < 1
    assert down[1] > up[1] + 5 and abs(down[0] - up[0]) < 1


def test_a_renderer_for_another_maze_on_the_board_draws_what_a_new_one_draws():
    from bimgame.sim.maze_sets import maze_number

    board = MazeRenderer(MazeSpec.merl(), 84)
    for number in range(4):
        maze = maze_number(number)
        fast = board.for_maze(maze)
        np.testing.assert_array_equal(fast.background, MazeRenderer(maze, 84).background)
        np.testing.assert_array_equal(fast.background_rgb(96), MazeRenderer(maze, 84).background_rgb(96))
        assert fast.spec == maze
    np.testing.assert_array_equal(board.background, MazeRenderer(MazeSpec.merl(), 84).background)  # unchanged
    with pytest.raises(ValueError, match="same board"):
        board.for_maze(MazeSpec.merl(marble_radius=5e-3))
