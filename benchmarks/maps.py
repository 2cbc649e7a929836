"""Synthetic benchmark maps: a straight lane through a field of octagonal pillars.

The lane (along ``y = 0``, 130 m long) and the pillar row on each side of it are the same in every
map; larger maps add rows of pillars farther out, so the platoon sees nearly the same local
geometry (in the smallest map the outer wall, 3.8 m from the lane, takes the place of the second
pillar row, 5.2 m away) while the number of boundary edges grows (about 200, 1,000 or 5,000). A
kernel that culls edges outside the sensing range costs about the same on all of them; a
brute-force one grows linearly.

Robot, camera and PPC parameters are those of study A (``d_des = 2``, ``d_con = 4``), so the lane
holds 50 followers (100 m) behind the leader with 26 m left to drive.
"""

from __future__ import annotations

import math
from typing import Any

#: Length of the lane [m]; the leader path runs along it.
LANE_LENGTH = 130.0
#: Distance from the lane's centre line to the centres of the first pillar row [m].
FIRST_ROW = 2.2
#: Spacing between rows [m] and between pillars along a row [m].
ROW_SPACING = 3.0
PILLAR_SPACING = 10.0
#: Circumradius of a pillar [m] and its number of sides (= edges).
PILLAR_RADIUS = 0.6
PILLAR_SIDES = 8


def _octagon(cx: float, cy: float) -> list[list[float]]:
    return [
        [
            round(cx + PILLAR_RADIUS * math.cos(2 * math.pi * (k + 0.5) / PILLAR_SIDES), 6),
            round(cy + PILLAR_RADIUS * math.sin(2 * math.pi * (k + 0.5) / PILLAR_SIDES), 6),
        ]
        for k in range(PILLAR_SIDES)
    ]


def rows_for_edges(n_edges: int) -> int:
    """Pillar rows per side that give about ``n_edges`` boundary edges (at least one)."""
    per_row = PILLAR_SIDES * (pillars_per_row() - 0.5)  # odd rows have one pillar fewer
    return max(1, round((n_edges - 4) / (2 * per_row)))


def pillars_per_row() -> int:
    """Number of pillars in one row along the lane."""
    return int(LANE_LENGTH // PILLAR_SPACING)


def pillar_lane(n_edges: int, followers: int = 7) -> dict[str, Any]:
    """A scenario dict (the schema of ``docs/scenarios.md``) with about ``n_edges`` boundary edges.

    ``followers`` must fit on the lane behind the leader (at most 55 with ``d_des = 2``).
    """
    rows = rows_for_edges(n_edges)
    count = pillars_per_row()
    half_width = FIRST_ROW + ROW_SPACING * (rows - 1) + PILLAR_RADIUS + 1.0
    obstacles = []
    for side in (-1.0, 1.0):
        for row in range(rows):
            cy = side * (FIRST_ROW + ROW_SPACING * row)
            # Stagger alternate rows so that the field is not a set of straight corridors.
            offset = 0.5 * PILLAR_SPACING * (row % 2)
            for k in range(count - row % 2):
                obstacles.append(_octagon(5.0 + offset + PILLAR_SPACING * k, cy))
    return {
        "name": f"pillar_lane_{n_edges}",
        "description": f"benchmark map: a lane through {rows} pillar row(s) per side",
        "workspace": {
            "bounds": [0.0, -half_width, LANE_LENGTH, half_width],
            "obstacles": obstacles,
        },
        "leader": {"path": [[1.0, 0.0], [LANE_LENGTH - 2.0, 0.0]], "speed": 0.5},
        "followers": followers,
        "robot": {"radius": 0.2},
        "camera": {"half_angle": math.pi / 4, "range": 4.0},
        "safety": {"d_col": 0.5},
        "formation": {"d_des": 2.0},
        "ppc": {
            "lambda": 1.0,
            "rho_d_inf": 0.1,
            "rho_beta_inf": 0.1,
            "k_d": 4.0,
            "k_beta": 4.0,
            "delta": 0.5,
            "epsilon": 0.75,
        },
    }
