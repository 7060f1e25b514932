"""Wall and layout solvers (paper Sections 4.1-4.3): from boundary rays to metric walls.

- ``wall``: the single-wall solvers (SVD null space of the side constraints, eqs. manx, many, quad_v, quad_w;
  the minimal 2 + 2 ray solver).
- ``horizontal_line``: the single-line baseline [bermudez2016line] of Section 5.3.
- ``wall_at_heights``: a wall at known ceiling and floor heights (a height prior's).
- ``wall_fit``: linear walls, the scale search and the Gauss-Newton refinement the solvers share.
- ``layout``: the joint Manhattan and Atlanta layout solvers.
- ``ransac``: RANSAC over one wall's columns with the single-wall solver.
"""

from .horizontal_line import HorizontalLine, solve_horizontal_line, solve_horizontal_lines
from .layout import (
    WallLayout,
    layout_corners,
    quarter_turn,
    ray_in_wall_frame,
    solve_atlanta_layout,
    solve_manhattan_layout,
)
from .wall import Wall, solve_wall, solve_wall_minimal

__all__ = [
    "HorizontalLine",
    "Wall",
    "WallLayout",
    "layout_corners",
    "quarter_turn",
    "ray_in_wall_frame",
    "solve_atlanta_layout",
    "solve_horizontal_line",
    "solve_horizontal_lines",
    "solve_manhattan_layout",
    "solve_wall",
    "solve_wall_minimal",
]
