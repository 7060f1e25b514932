"""Wall and layout solvers (paper Sections 4.1-4.3): from boundary rays to metric walls.

- ``wall``: the single-wall solvers (SVD null space of the side constraints, eqs. manx, many, quad_v, quad_w;
  the minimal 2 + 2 ray solver).
- ``horizontal_line``: the single-line baseline [bermudez2016line] of Section 5.3.
- ``wall_at_heights``: a wall at known ceiling and floor heights (a height prior's).
- ``wall_fit``: linear walls, the scale search and the Gauss-Newton refinement the solvers share.
- ``layout``: the joint Manhattan and Atlanta layout solvers.
- ``ransac``: RANSAC over one wall's columns with the single-wall solver.
"""
