"""How much a non-central rig's rows tell the scale: the rows' change when the room is taken a factor too large.

A rig of radius ``rc`` sees a room and the same room scaled by ``s`` about its axis (heights too) at different rows
only through the parallax of its circle of optical centres. The scaled room is refitted to the exact rows of the
true one, walls and the other height free but the floor's height below the camera (the ceiling's above it for the
ceiling's rows alone) held at ``s`` times the truth, so that its scale is ``s``; the rows of the best such room
differ from the truth's by an RMS of ``e(s)`` pixels. Rows whose errors along a wall exceed ``e(s)`` cannot tell
the room from its copy scaled by ``s``: ``e(s)`` is the budget of row error within which the rows fix the scale.

Rooms are rectangles (Manhattan; the refit: the yaw, the four walls' distances and the free height), the
camera off the room's centre by (15%, 10%) of its sides, 1.2 m above the floor, the ceiling 2.7 m above the floor; the
panorama is 1024 x 512. Printed: ``e(s)`` for ``s`` = 0.8 and 1.25 (a fifth smaller, a quarter larger) per
room size and ``rc``, and the same for the rows of the floor alone and of the ceiling alone (the other boundary
hidden: desks along the walls, a fan); "-" where the nearest wall is nearer than 1.5 radii.

With ``--panorama FILE`` (a rig's capture; ``rc`` from its name, as ``ncjax reconstruct --rc auto``; levelled as
``ncjax reconstruct`` levels it) it measures the same on the network's rows instead: per wall (the columns between
two of the pipeline's corner peaks, 5 columns kept clear of each), the line that best fits the rows of one boundary
at an assumed height of that boundary (angle and distance free, robust soft-L1 loss of the row residuals), and the
median absolute residual over all walls' rows, for heights from 0.2 to 10 m: rows that fix the scale fit best near
one height.

    uv run python experiments/parallax_budget.py [--sizes 3 5 8 12] [--radii 0.05 0.2 0.4 0.6 1.0]
    uv run python experiments/parallax_budget.py --panorama ../shared/data/noncentral-real/L101_R06101.png \
        [--ratio-columns 0:31]

It also prints the rows' ratio of the ceiling's height above the camera to the floor's below it (per column,
``tan(phi_c) / -tan(phi_f)``), which a camera-height prior turns into the room's height: over all columns, and over
``--ratio-columns``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares

import ncjax
from ncjax.cli.outputs import MIN_RIG_TILT, align_to_gravity
from ncjax.geometry.camera import NonCentralPanorama
from ncjax.geometry.reprojection import boundary_points, wall_boundary_rows
from ncjax.io.images import rc_from_name, read_panorama
from ncjax.pipeline.corners import configured_corners
from ncjax.pipeline.floor_check import column_height_ratios

WIDTH, HEIGHT = 1024, 512
CAMERA_HEIGHT, ROOM_HEIGHT = 1.2, 2.7
CAMERA_OFFSET = (0.15, 0.10)  # fractions of the room's sides
ASPECT = 0.75  # depth / width
SCALES = (0.8, 1.25)
PROFILE_HEIGHTS = (0.2, 0.3, 0.5, 0.8, 1.2, 1.6, 2.0, 3.0, 5.0, 10.0)
CORNER_MARGIN = 5  # columns kept clear of each corner peak in the profile
MIN_WALL_COLUMNS = 20
MIN_WALL_RADII = 1.5  # a room whose nearest wall is nearer than this many radii (of the rig) is left out
BOUNDARIES = ("both", "floor", "ceiling")


def rectangle_walls(yaw, distances):
    """The four walls (unit directions, signed distances) of a rectangle turned by ``yaw``, in azimuth order."""
    angles = yaw + jnp.arange(4) * (jnp.pi / 2)
    return jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1), distances


def room_rows(cam, params):
    """Every column's ceiling and floor rows of the room ``params`` = (yaw, 4 distances, h_c, h_f): each column
    sees the wall its ray meets first."""
    yaw, distances, ceiling_height, floor_height = params[0], params[1:5], params[5], params[6]
    directions, distances = rectangle_walls(yaw, distances)
    columns = jnp.arange(cam.width, dtype=jnp.float64)
    rows = jax.vmap(lambda u, d: wall_boundary_rows(cam, u, d, ceiling_height, floor_height, columns), out_axes=0)(
        directions, distances
    )
    ceiling_v, floor_v, seen = rows
    # inside a convex room a column's ray meets the room's wall first: the nearest, whose floor row is the lowest
    nearest = jnp.argmax(jnp.where(seen, floor_v, -jnp.inf), axis=0)
    pick = jnp.arange(cam.width)
    return ceiling_v[nearest, pick], floor_v[nearest, pick]


def true_room(size: float) -> np.ndarray:
    """(yaw, distances, h_c, h_f) of a ``size`` x ``ASPECT size`` room, the camera off its centre."""
    width, depth = size, ASPECT * size
    dx, dy = CAMERA_OFFSET[0] * width, CAMERA_OFFSET[1] * depth
    # walls y = -depth/2 - dy, x = width/2 + dx, y = depth/2 - dy, x = -width/2 + dx (the room's centre at (dx, -dy)),
    # each as e2 . p = d with e2 = (-uy, ux)
    distances = [-(depth / 2 + dy), -(width / 2 + dx), -(depth / 2 - dy), -(width / 2 - dx)]
    return np.array([0.0, *distances, ROOM_HEIGHT - CAMERA_HEIGHT, -CAMERA_HEIGHT])


def refit_error(cam, truth: np.ndarray, scale: float, boundary: str) -> float:
    """RMS row difference (px) of the best room whose ``boundary`` height (the floor's for both) is ``scale`` times
    the truth's from the true rows of ``boundary``: yaw, distances and the other height free."""
    target = [np.asarray(x) for x in room_rows(cam, jnp.asarray(truth))]
    used = {"both": (0, 1), "floor": (1,), "ceiling": (0,)}[boundary]
    held = 5 if boundary == "ceiling" else 6  # the index of the height held at scale times the truth

    @jax.jit
    def residuals(free):
        params = jnp.insert(free, held, scale * truth[held])
        rows = room_rows(cam, params)
        return jnp.concatenate([rows[i] - target[i] for i in used])

    jacobian = jax.jit(jax.jacfwd(residuals))
    start = np.delete(np.concatenate([[truth[0]], scale * truth[1:]]), held)
    fit = least_squares(lambda x: np.asarray(residuals(x)), start, jac=lambda x: np.asarray(jacobian(x)), x_scale="jac")
    return float(np.sqrt(np.mean(fit.fun**2)))


def wall_stretches(corner_prob: np.ndarray) -> list[np.ndarray]:
    """The columns of each wall between two of the pipeline's corner peaks, clear of the peaks."""
    columns, mask, _, _ = configured_corners(jnp.asarray(corner_prob, jnp.float32), ncjax.NETWORK_PIPELINE_CONFIG)
    peaks = np.sort(np.asarray(columns)[np.asarray(mask)])
    width = corner_prob.shape[0]
    stretches = []
    for start, end in zip(peaks, np.append(peaks[1:], peaks[0] + width), strict=True):
        stretch = np.arange(int(np.ceil(start)) + CORNER_MARGIN, int(np.floor(end)) - CORNER_MARGIN + 1) % width
        if len(stretch) >= MIN_WALL_COLUMNS:
            stretches.append(stretch)
    return stretches


@jax.jit
def padded_residuals(cam, line, height, columns, observed, boundary_is_floor):
    """Row residuals (px) of the wall ``line`` = (angle, distance) at ``height`` over ``columns`` (padded with NaN
    rows: residual 0)."""
    direction = jnp.stack([jnp.cos(line[0]), jnp.sin(line[0])])
    ceiling, floor, _ = wall_boundary_rows(cam, direction, line[1], height, -height, columns)
    residual = jnp.where(boundary_is_floor, floor, ceiling) - observed
    return jnp.where(jnp.isfinite(observed), residual, 0.0)


def wall_residuals(cam, rows: np.ndarray, columns: np.ndarray, height: float, boundary: int) -> np.ndarray:
    """Row residuals (px) of the line at ``height`` that fits ``rows`` of ``columns`` best (soft-L1)."""
    usable = columns[np.isfinite(rows[columns])]
    padded = np.zeros(cam.width)
    padded[: len(usable)] = usable
    observed = np.full(cam.width, np.nan)
    observed[: len(usable)] = rows[usable]
    arguments = (jnp.asarray(height), jnp.asarray(padded), jnp.asarray(observed), jnp.asarray(boundary == 1))

    def residuals(line):
        return np.asarray(padded_residuals(cam, jnp.asarray(line), *arguments))[: len(usable)]

    # start: the wall facing the stretch's middle column through its boundary point at the assumed height; a wall of
    # direction u and distance d holds the points p with (-uy, ux) . p = d, so one facing a ray of azimuth a has u at
    # a + 90 degrees and d = -|p|
    middle = usable[len(usable) // 2]
    point, reached = boundary_points(cam, float(middle), float(rows[middle]), height if boundary == 0 else -height)
    point = np.asarray(point, np.float64)
    azimuth = float(np.arctan2(point[1], point[0]))
    reach = float(np.linalg.norm(point)) if bool(reached) else float(cam.rc) + height
    fit = least_squares(residuals, np.array([azimuth + np.pi / 2, -reach]), loss="soft_l1", f_scale=2.0)
    return fit.fun


def profile(path: Path, ratio_columns: tuple[int, int] | None) -> None:
    """Print the median absolute row residual of the best walls at each assumed height (module docstring), and the
    rows' ratio of the ceiling's height to the floor's over all columns and over ``ratio_columns`` [start, end)."""
    rc = rc_from_name(path.name)
    if rc is None:
        raise SystemExit(f"parallax_budget: error: {path.name} gives no radius (e.g. L101_R06101.png: rc 0.6101 m)")
    image = read_panorama(path)
    if ratio_columns is not None and ratio_columns[1] > image.shape[1]:
        raise SystemExit(f"parallax_budget: error: --ratio-columns ends past the image's {image.shape[1]} columns")
    image, _ = align_to_gravity(image, MIN_RIG_TILT)  # levelled first, as ncjax reconstruct levels a rig's
    ceiling_v, floor_v, corner_prob = (np.asarray(a, np.float64) for a in ncjax.predict_boundaries(image, views=4))
    stretches = wall_stretches(corner_prob)
    cam = NonCentralPanorama(image.shape[1], image.shape[0], rc)
    with jax.enable_x64(True):  # the fits in float64 (the network above runs in float32)
        profile_table(cam, ceiling_v, floor_v, stretches)
    print(f"{path.name}: rc {rc} m, {len(stretches)} walls of >= {MIN_WALL_COLUMNS} columns")
    # h_c / -h_f per column: the ratio of the ceiling's height above the camera to the floor's below it
    ratios = -np.asarray(column_height_ratios(cam, *(jnp.asarray(v, jnp.float32) for v in (ceiling_v, floor_v))))
    low, median, high = np.nanquantile(ratios, [0.1, 0.5, 0.9])
    print(f"ceiling height / floor depth, per column: median {median:.2f} (10-90% {low:.2f}-{high:.2f})")
    if ratio_columns is not None:
        start, end = ratio_columns
        print(f"  over columns {start}-{end - 1}: median {np.nanmedian(ratios[start:end]):.2f}")


def profile_table(cam, ceiling_v: np.ndarray, floor_v: np.ndarray, stretches: list[np.ndarray]) -> None:
    """The profile's table: per assumed height, the median absolute residual of each boundary's best walls."""
    print("| height of the boundary (m) | ceiling rows: median abs residual (px) | floor rows |")
    print("| --- | --- | --- |")
    for height in PROFILE_HEIGHTS:
        cells = []
        for boundary, rows in enumerate((ceiling_v, floor_v)):
            residual = np.concatenate([wall_residuals(cam, rows, stretch, height, boundary) for stretch in stretches])
            cells.append(f"{np.median(np.abs(residual)):.3f}")
        print(f"| {height:g} | " + " | ".join(cells) + " |", flush=True)


def budget_tables(sizes: list[float], radii: list[float]) -> None:
    """The budget's tables (module docstring): ``e(s)`` per boundary, room size and radius."""
    header = " | ".join(f"rc {rc:g} m" for rc in radii)
    for boundary in BOUNDARIES:
        print(f"\nrows of {boundary}: RMS px of the best room a fifth smaller / a quarter larger (1024 x 512)")
        print(f"| room (m) | {header} |")
        print("| --- |" + " --- |" * len(radii))
        for size in sizes:
            truth = true_room(size)
            cells = []
            for rc in radii:
                if np.min(np.abs(truth[1:5])) < MIN_WALL_RADII * rc:
                    cells.append("-")
                    continue
                cam = NonCentralPanorama(WIDTH, HEIGHT, rc)
                cells.append(" / ".join(f"{refit_error(cam, truth, s, boundary):.2f}" for s in SCALES))
            print(f"| {size:g} x {ASPECT * size:g} | " + " | ".join(cells) + " |", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[3.0, 5.0, 8.0, 12.0], help="room widths (m)")
    parser.add_argument("--radii", type=float, nargs="+", default=[0.05, 0.2, 0.4, 0.6, 1.0], help="rc (m)")
    parser.add_argument("--panorama", type=Path, help="a rig's capture: the profile of its network rows instead")
    parser.add_argument(
        "--ratio-columns", metavar="START:END", help="with --panorama, also the height ratio over these columns"
    )
    args = parser.parse_args(argv)
    if args.panorama is not None:
        if not args.panorama.is_file():
            parser.error(f"no file {args.panorama}")
        ratio_columns = None
        if args.ratio_columns is not None:
            try:
                ratio_columns = tuple(int(x) for x in args.ratio_columns.split(":"))
            except ValueError:
                ratio_columns = ()
            if len(ratio_columns) != 2 or not 0 <= ratio_columns[0] < ratio_columns[1]:
                parser.error(f"--ratio-columns must be START:END with 0 <= START < END, got {args.ratio_columns}")
        profile(args.panorama, ratio_columns)
        return 0
    if min(args.sizes) <= 0 or min(args.radii) <= 0:
        parser.error("room sizes and radii must be > 0")
    with jax.enable_x64(True):  # exact rows: the differences sought are hundredths of a pixel
        budget_tables(args.sizes, args.radii)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
