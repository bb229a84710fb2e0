"""The three boards CyberRunner played: the BRIO labyrinth's easy, medium and hard layouts as data.

Source. Bi & D'Andrea, "Sample-Efficient Learning to Solve a Real-World Labyrinth Game Using
Data-Augmented Model-Based Reinforcement Learning" (ETH Zurich, 2023, arXiv 2312.09906) and its
repository ``thomasbi1/cyberrunner``, file ``cyberrunner_dreamer/cyberrunner_dreamer/cyberrunner_layout.py``
at commit ``f148e4e744f2f822b621d084f3cc93627f9c7002``, which lists for each layout the horizontal
and vertical wall segments, the hole centres and the waypoints of the path, measured on the physical
board. The numbers below are those measurements, transcribed by hand into millimetre tables of our
own (no code of that AGPL repository is used). The only difference between that commit and the
repository's other stored version (``7b63cbe3d4bc1371dc94942ce4b7e5b573928383``) is the hard
layout's waypoints 18 and 19, at x = 17 mm there and 10 mm in the other; the later commit (its
``path.py`` also grew a jump-detection tool) is the one used.

Frames. The repository measures in metres from the board's lower-left corner (x right along the
0.276 m side, y up along the 0.231 m side; its state estimator adds half the board to centred
coordinates, ``cyberrunner_dreamer/env.py``). bimgame's board frame has its origin at the board's
centre, x right and y up, the frame :class:`~bimgame.sim.labyrinth_physics.LabyrinthSim` tilts
about: a point ``(x, y)`` of the tables maps to ``(x / 1000 - 0.138, y / 1000 - 0.1155)`` m. No axis
is flipped. The board's edges ``x = 0, 0.276`` and ``y = 0, 0.231`` are the inner faces of the rim:
``cyberrunner_state_estimation/core/plate_pose.py`` puts the maze's corners 7.5 mm (``edge_width``)
inside corner markers 0.2835 m x 0.2385 m apart, i.e. exactly 0.276 m x 0.231 m, and inner walls
that end at ``x = 0`` meet the rim there.

Walls. A horizontal wall ``(x_start, x_end, y)`` is the rectangle ``[x_start, x_end]`` along x and
``y ± t/2`` across; a vertical one ``(y_start, y_end, x)`` likewise. The thickness ``t`` is the
repository's wall "radius" doubled (``path.py``: ``wall_r = 0.0025``, so t = 5 mm): with it, walls
that meet at a corner meet face to face (e.g. the medium layout's wall along y = 199 mm ends at the
5 mm wide wall at x = 45.5 mm, whose end is at 199 + 2.5 mm), so the ends are taken as exact, not
extended by t/2.
"""

from __future__ import annotations

import dataclasses
import math

__all__ = [
    "BOARD_SIZE",
    "WALL_THICKNESS",
    "LAYOUT_NAMES",
    "LabyrinthLayout",
    "get_layout",
]

#: Playable board (m): inside the rim, x by y (``cyberrunner_layout.py`` / ``path.py``: 0.276 × 0.231).
BOARD_SIZE: tuple[float, float] = (0.276, 0.231)
#: Thickness of the inner walls (m): twice ``wall_r = 0.0025`` of ``path.py``.
WALL_THICKNESS = 0.005

#: A wall rectangle in the board frame (m): ``(x_min, y_min, x_max, y_max)``.
Rect = tuple[float, float, float, float]
Point = tuple[float, float]

# ------------------------------------------------------------------------------------------------
# Tables in millimetres, from the board's lower-left corner (see the module docstring).
# Horizontal walls: (x_start, x_end, y). Vertical walls: (y_start, y_end, x). Points: (x, y).
# ------------------------------------------------------------------------------------------------
_EASY_MM: dict[str, tuple[tuple[float, ...], ...]] = {
    "horizontal": (
        (45, 154, 211.5), (159, 176, 185.5), (24, 111, 173), (116, 171, 154.5), (50, 156.5, 73.5),
        (26.5, 45, 49), (0, 87.5, 113.5), (0, 16.5, 85.5), (77, 188.5, 20), (162.5, 183.5, 110),
        (188.5, 224.5, 69), (229.5, 247.5, 69), (188.5, 224.5, 128.5), (229.5, 245, 154), (213.5, 242, 185),
        (196, 213.5, 206.5), (252, 276, 107), (258.5, 276, 171.5),
    ),
    "vertical": (
        (199, 214, 42.5), (183, 231, 156.5), (159, 184, 21.5), (76, 175.5, 113.5), (46.5, 83.5, 47.5),
        (46.5, 71, 103), (116, 132, 35.5), (116, 132, 70.5), (0, 44, 74.5), (22.5, 36.5, 137),
        (22.5, 131, 186), (46, 182.5, 227), (187.5, 209, 216), (0, 29.5, 213.5),
    ),
    "holes": (
        (31.5, 186.5), (55, 128), (32, 64), (173.5, 33.5), (150, 110), (174, 170), (241.5, 142), (241.5, 55),
    ),
    "waypoints": (
        (140.5, 222), (41.5, 222), (9, 197), (9, 159), (27.5, 142.5), (61, 153), (89, 143), (102, 116),
        (74, 93), (48, 98), (27.5, 87), (12, 57), (12, 29), (61, 29), (61, 58), (89, 58), (89, 35),
        (120, 35), (120, 58), (170, 58), (170, 91), (130, 91), (130, 121), (200, 156), (200, 187),
        (181, 219), (232, 219), (253, 186), (253, 169), (264, 137), (242, 113), (242, 94), (264, 74),
        (264, 40), (202, 40), (202, 7), (93.5, 7),
    ),
}  # fmt: skip

_MEDIUM_MM: dict[str, tuple[tuple[float, ...], ...]] = {
    "horizontal": (
        (0, 48, 199), (0, 58, 145), (0, 58, 118), (27, 40.5, 76), (0, 43, 29.5), (72, 81, 173.5),
        (72, 178, 210), (183, 276, 213), (66, 131, 94.5), (86.5, 102, 120.5), (68, 91.5, 42.5),
        (96.5, 206, 31), (118.5, 159, 168.5), (164, 179, 85), (189, 213.5, 111), (218.5, 276, 123.5),
        (218.5, 244, 89.5), (244, 276, 154), (184, 210, 162.5), (226, 251, 192),
    ),
    "vertical": (
        (201.5, 231, 45.5), (147.5, 178, 35), (59, 89, 43), (0, 42, 45.5), (188, 231, 180.5),
        (171, 212.5, 69.5), (97, 147, 84), (71.5, 92, 68.5), (52, 92, 128.5), (0, 68, 94),
        (33.5, 62.5, 187), (114, 142, 140), (144, 183, 116), (77, 171, 161.5), (0, 53, 230),
        (87, 126, 216), (66.5, 92, 246.5), (150.5, 160, 186.5), (165, 174, 207.5), (180.5, 189.5, 228.5),
    ),
    "holes": (
        (30, 186.5), (57, 130), (56.5, 87.5), (31, 65), (58, 36), (105, 70), (175, 69.5), (150, 111),
        (127.5, 148.5), (80, 160), (81, 186), (152, 193), (219, 176), (242.5, 143), (175, 143), (242, 57.5),
    ),
    "waypoints": (
        (166, 220.5), (57, 220.5), (57, 160), (72, 144), (72, 105), (15, 105), (15, 45.5), (81, 60),
        (81, 83), (119.5, 83), (119.5, 43), (144, 43), (144, 96), (99, 139), (99, 194), (129.5, 194),
        (129.5, 179), (190, 179), (213, 201), (264, 201), (264, 174), (239, 174), (219, 145), (176, 124),
        (176, 97), (198, 97), (198, 72), (218, 51), (218, 15), (108, 15),
    ),
}  # fmt: skip

_HARD_MM: dict[str, tuple[tuple[float, ...], ...]] = {
    "horizontal": (
        (0, 25, 204.5), (0, 25, 159), (15, 25, 182), (94.5, 159.5, 204.5), (94.5, 113.5, 155.5),
        (15, 42.5, 137), (15, 42.5, 79.5), (0, 13.5, 36.5), (94.5, 118.5, 58), (118.5, 141.5, 79.5),
        (164.5, 210.5, 155.5), (164.5, 182.5, 184.5), (159.5, 188.5, 24), (187.5, 205.5, 72.5),
        (182.5, 205.5, 107.5), (210.5, 228.5, 191.5), (257.5, 276, 101.5), (252.5, 276, 210),
    ),
    "vertical": (
        (187, 207, 45), (134.5, 177, 45), (143, 161, 69), (177, 192, 69), (213, 231, 69), (139, 158, 92),
        (177, 207, 92), (153, 186, 116), (132, 152, 139), (169, 187, 139), (117, 231, 162), (92, 137, 208),
        (175, 194, 208), (122, 194, 231), (213, 231, 231), (166, 191, 255), (99, 150, 255), (60, 102, 162),
        (70, 92, 185), (21, 75, 208), (21, 38, 231), (53, 104, 231), (0, 18, 255), (98, 121, 22),
        (98, 121, 45), (93, 121, 69), (93, 121, 92), (21, 82, 45), (34, 52, 69), (0, 14, 69), (21, 60, 92),
        (21, 38, 116), (77, 132, 116), (21, 60, 139), (99, 117, 139),
    ),
    "holes": (
        (11, 216), (34, 185), (57, 185), (81, 185), (150, 191), (58, 128), (81, 157), (104, 143), (127, 146),
        (174, 216), (219, 216), (242, 216), (266, 198), (219, 178), (174, 170), (173, 143), (243, 143),
        (219, 132), (196, 120), (266, 88), (266, 43), (243, 58), (243, 13), (219, 58), (174, 13), (174, 38),
        (174, 71), (10, 107), (10, 50), (34, 67), (34, 25), (57, 88), (57, 37), (81, 107), (81, 70), (81, 12),
        (104, 71), (127, 31), (150, 111), (150, 58),
    ),
    "waypoints": (
        (150, 218), (80, 218), (80, 203), (56, 203), (56, 218), (34, 218), (34, 195), (9, 195), (9, 167),
        (33, 167), (33, 149), (7, 149), (7, 129), (33, 129), (33, 91), (7, 91), (7, 69), (29, 50), (17, 25),
        (17, 10), (50, 10), (80, 34), (80, 59), (62, 59), (62, 73), (75, 85), (104, 85), (104, 130),
        (75, 130), (57, 143), (57, 170), (104, 170), (104, 193), (128, 193), (128, 162), (150, 162),
        (150, 125), (127, 125), (127, 90), (150, 90), (150, 69), (127, 69), (127, 46), (104, 46), (104, 11),
        (150, 11), (150, 38), (171, 53), (197, 53), (197, 10), (220, 10), (220, 45), (247, 45), (261, 58),
        (243, 77), (243, 113), (219, 113), (219, 83), (197, 83), (197, 98), (173, 98), (173, 121),
        (199, 145), (219, 145), (219, 166), (195, 166), (195, 203), (244, 203), (244, 159), (266, 159),
        (266, 112),
    ),
}  # fmt: skip

_TABLES = {"easy": _EASY_MM, "medium": _MEDIUM_MM, "hard": _HARD_MM}
#: The layouts the repository publishes, easiest first.
LAYOUT_NAMES: tuple[str, ...] = tuple(_TABLES)


@dataclasses.dataclass(frozen=True)
class LabyrinthLayout:
    """One board in bimgame's board frame (m; origin at the board's centre, x right, y up).

    Attributes:
        name: the layout's name (one of :data:`LAYOUT_NAMES`).
        walls: inner walls as axis-aligned rectangles ``(x_min, y_min, x_max, y_max)`` (the rim is
            not among them: it follows from the board size).
        holes: hole centres ``(x, y)``.
        waypoints: the path from start to goal, in order; the first is the start, the last the goal.
    """

    name: str
    walls: tuple[Rect, ...]
    holes: tuple[Point, ...]
    waypoints: tuple[Point, ...]

    @property
    def start(self) -> Point:
        """Where the marble starts: the path's first waypoint."""
        return self.waypoints[0]

    @property
    def goal(self) -> Point:
        """Where the path ends: its last waypoint."""
        return self.waypoints[-1]


def _to_board(x_mm: float, y_mm: float) -> Point:
    """A table point (mm from the lower-left corner) in the centred board frame (m)."""
    return (x_mm / 1000 - BOARD_SIZE[0] / 2, y_mm / 1000 - BOARD_SIZE[1] / 2)


def _wall_rects(table: dict[str, tuple[tuple[float, ...], ...]], thickness: float) -> tuple[Rect, ...]:
    """The table's wall segments as rectangles ``thickness`` thick, horizontal ones first."""
    half = thickness / 2
    rects: list[Rect] = []
    for x0, x1, y in table["horizontal"]:
        (ax, ay), (bx, by) = _to_board(x0, y), _to_board(x1, y)
        rects.append((ax, ay - half, bx, by + half))
    for y0, y1, x in table["vertical"]:
        (ax, ay), (bx, by) = _to_board(x, y0), _to_board(x, y1)
        rects.append((ax - half, ay, bx + half, by))
    return tuple(rects)


def get_layout(name: str, wall_thickness: float = WALL_THICKNESS) -> LabyrinthLayout:
    """The layout ``name`` (``"easy"``, ``"medium"`` or ``"hard"``) with walls ``wall_thickness``
    (m) thick (default: the repository's 5 mm). Raises ``ValueError`` naming the allowed names."""
    if name not in _TABLES:
        raise ValueError(f"layout must be one of {', '.join(map(repr, LAYOUT_NAMES))}, got {name!r}")
    if not (isinstance(wall_thickness, (int, float)) and math.isfinite(wall_thickness) and wall_thickness > 0):
        raise ValueError(f"wall_thickness must be a positive number of metres, got {wall_thickness!r}")
    table = _TABLES[name]
    return LabyrinthLayout(
        name=name,
        walls=_wall_rects(table, float(wall_thickness)),
        holes=tuple(_to_board(x, y) for x, y in table["holes"]),
        waypoints=tuple(_to_board(x, y) for x, y in table["waypoints"]),
    )
