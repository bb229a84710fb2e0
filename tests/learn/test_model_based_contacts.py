"""Tests of the model-based learner's wall contacts (bimgame.learn.model_based.contacts): a marble
predicted into a wall or past the rim ends at the marble's radius from it, without the velocity into
it and with the velocity along it; a free marble is left alone."""

from __future__ import annotations

import numpy as np
import pytest

from bimgame.learn.model_based.contacts import WallContacts
from bimgame.sim.labyrinth import LabyrinthSpec


@pytest.fixture(scope="module")
def hard() -> LabyrinthSpec:
    return LabyrinthSpec.layout("hard")


def _a_wall(spec):
    """The longest inner wall running along x, and a point just below its middle."""
    walls = np.asarray(spec.walls)
    wall = walls[np.argmax((walls[:, 2] - walls[:, 0]) - (walls[:, 3] - walls[:, 1]))]
    return wall, np.array([(wall[0] + wall[2]) / 2, wall[1]])


def test_a_marble_pressed_into_a_wall_ends_at_its_radius_keeping_the_velocity_along_it(hard):
    contacts = WallContacts(hard)
    wall, face = _a_wall(hard)
    xy = face - [0.0, 0.6 * hard.marble_radius]  # its centre 0.4 radius too close to the wall's lower face
    if float(hard.clearance(xy)) < 0.6 * hard.marble_radius - 1e-9:
        pytest.skip("another wall is as close: not a plain face")
    out, velocity = contacts.resolve(xy[None], np.array([[0.05, 0.2]]))
    assert float(hard.clearance(out[0])) == pytest.approx(hard.marble_radius, abs=1e-9)
    assert out[0, 0] == pytest.approx(xy[0])  # pushed straight out of the face
    assert velocity[0].tolist() == pytest.approx([0.05, 0.0])  # into the wall removed, along it kept


def test_a_marble_moving_away_from_a_wall_it_touches_keeps_its_velocity(hard):
    wall, face = _a_wall(hard)
    xy = face - [0.0, 0.9 * hard.marble_radius]
    _, velocity = WallContacts(hard).resolve(xy[None], np.array([[0.03, -0.1]]))
    assert velocity[0].tolist() == pytest.approx([0.03, -0.1])


def test_a_free_marble_is_left_alone_and_the_inputs_are_not_modified(hard):
    contacts = WallContacts(hard)
    rng = np.random.default_rng(0)
    hx, hy = np.asarray(hard.board_size) / 2
    xy = rng.uniform([-hx, -hy], [hx, hy], size=(400, 2))
    free = xy[hard.clearance(xy) > hard.marble_radius]
    velocity = rng.normal(0, 0.1, size=free.shape)
    kept_xy, kept_v = free.copy(), velocity.copy()
    out, out_v = contacts.resolve(free, velocity)
    assert len(free) > 20
    np.testing.assert_array_equal(out, kept_xy)
    np.testing.assert_array_equal(out_v, kept_v)
    np.testing.assert_array_equal(free, kept_xy)


def test_every_resolved_marble_clears_walls_and_rim_wherever_it_was_predicted(hard):
    rng = np.random.default_rng(1)
    hx, hy = np.asarray(hard.board_size) / 2
    xy = rng.uniform([-hx, -hy], [hx, hy], size=(4000, 2))
    xy = xy[hard.clearance(xy) >= hard.marble_radius]  # where a marble can be
    angle = rng.uniform(0, 2 * np.pi, len(xy))  # then a step of up to 0.6 radius (0.2 m/s at 55 Hz)
    moved = xy + 0.6 * hard.marble_radius * rng.uniform(0, 1, (len(xy), 1)) * np.c_[np.cos(angle), np.sin(angle)]
    out, velocity = WallContacts(hard).resolve(moved, rng.normal(0, 0.1, size=moved.shape))
    assert len(xy) > 500
    assert np.all(hard.clearance(out) >= hard.marble_radius - 1e-5)  # within 10 µm


def test_the_rim_stops_outward_motion(hard):
    hx = hard.board_size[0] / 2
    out, velocity = WallContacts(hard).resolve(np.array([[hx, 0.0]]), np.array([[0.2, 0.1]]))
    assert out[0, 0] == pytest.approx(hx - hard.marble_radius)
    assert velocity[0].tolist() == pytest.approx([0.0, 0.1])


def test_a_board_is_required():
    with pytest.raises(TypeError, match="LabyrinthSpec"):
        WallContacts("hard")  # type: ignore[arg-type]
