"""The viewer of one result: one HTML file that shows the textured room in 3D in a browser, offline.

The page carries everything it needs, so that it opens from the file system with no network: the room's
surfaces and corners as JSON, the texture as a JPEG data URL, the viewer's script and three.js (vendored in
``ncjax/viz/web``: ``three.module.min.js`` and ``OrbitControls.js`` of the npm package ``three``, MIT,
its licence in ``three-LICENSE``). Browsers refuse to load module files from ``file://``, so the modules
come as ``data:`` URLs in an import map.
"""

from __future__ import annotations

import base64
import html
import json
import math
import pathlib
import string

import numpy as np

from ..io.export import PathLike
from ..io.files import write_atomic
from ..io.mesh import TexturedRoom, texture_jpeg, z_up_to_y_up
from ..pipeline.types import FLAGGED_STATUSES, LayoutStatus
from .room_texture import UNSEEN_COLOUR

WEB = pathlib.Path(__file__).parent / "web"
# the modules of three.js the viewer imports, by the names it imports them under
MODULES = {"three": "three.module.min.js", "three/addons/controls/OrbitControls.js": "OrbitControls.js"}
# the 95% quantile of the chi-square distribution with 2 degrees of freedom: -2 ln(0.05)
CHI2_95 = -2.0 * math.log(0.05)
ELLIPSE_POINTS = 48
# the ellipses lie this far above the floor, so that the floor does not cover them
ELLIPSE_LIFT = 0.01


def viewer_scene(room: TexturedRoom, record: dict) -> dict:
    """What the viewer shows of a result, as JSON: its surfaces, corners, ellipses and figures (metres, y up).

    Args:
        room: the textured room (:func:`~ncjax.viz.room_texture.textured_room`).
        record: its JSON record (:func:`~ncjax.io.export.layout_record`), of a layout with its geometry.
    """
    status = LayoutStatus[record["status"]]
    walls = record["walls"]
    surfaces = []
    for surface in room.surfaces:
        kind, _, index = surface.name.partition(" ")
        surfaces.append(
            {
                "name": surface.name,
                "inserted": kind == "wall" and walls[int(index)]["inserted"],
                "positions": z_up_to_y_up(surface.vertices).ravel().tolist(),
                "uv": surface.uv.ravel().tolist(),
                "indices": surface.faces.ravel().tolist(),
            }
        )
    return {
        "name": record["name"],
        "ok": record["ok"],
        "status": status.name if record["ok"] else f"{status.name} (flagged)",
        "flag": FLAGGED_STATUSES[status].upper() if status in FLAGGED_STATUSES else None,
        "reason": status.reason,
        "room_height": record["room_height"],
        "room_height_sigma": record["room_height_sigma"],
        "floor_area": record["floor_area"],
        "perimeter": record["perimeter"],
        "walls": [{"length": wall["length"], "inserted": wall["inserted"]} for wall in walls],
        "corners": {
            "floor": z_up_to_y_up(np.array(record["floor_corners"])).tolist(),
            "ceiling": z_up_to_y_up(np.array(record["ceiling_corners"])).tolist(),
        },
        "ellipses": corner_ellipses(record),
        "surfaces": surfaces,
        "texture": "data:image/jpeg;base64," + base64.b64encode(texture_jpeg(room.texture)).decode("ascii"),
    }


def corner_ellipses(record: dict) -> list[list[list[float]]]:
    """The 95% ellipse of each corner whose plan covariance is known, as a closed outline just above the floor."""
    angle = np.linspace(0.0, 2.0 * math.pi, ELLIPSE_POINTS, endpoint=False)
    circle = np.stack([np.cos(angle), np.sin(angle)])
    outlines = []
    for corner, covariance in zip(record["floor_corners"], record["corner_covariance"], strict=True):
        covariance = np.array(covariance, dtype=np.float64)  # None (not determined) becomes NaN
        if not np.all(np.isfinite(covariance)):
            continue
        variances, axes = np.linalg.eigh(covariance)
        plan = np.array(corner[:2])[:, None] + axes @ (np.sqrt(CHI2_95 * np.maximum(variances, 0.0))[:, None] * circle)
        heights = np.full((1, ELLIPSE_POINTS), corner[2] + ELLIPSE_LIFT)
        outlines.append(z_up_to_y_up(np.concatenate([plan, heights]).T).tolist())
    return outlines


def _script_text(text: str) -> str:
    """``text`` safe inside an HTML script element (JSON's ``<`` escaped; nothing can close the element)."""
    return text.replace("<", "\\u003c")


def viewer_html(room: TexturedRoom, record: dict) -> str:
    """The viewer's page of one result (see the module docstring)."""
    imports = {
        name: "data:text/javascript;base64," + base64.b64encode((WEB / file).read_bytes()).decode("ascii")
        for name, file in MODULES.items()
    }
    viewer = (WEB / "viewer.js").read_text()
    if "</script" in viewer.lower():
        raise ValueError("viewer.js may not hold '</script'")
    page = string.Template((WEB / "viewer.html").read_text())
    return page.substitute(
        title=html.escape(f"{record['name']}: the room in 3D (ncjax)"),
        unseen=", ".join(map(str, UNSEEN_COLOUR)),
        scene=_script_text(json.dumps(viewer_scene(room, record), separators=(",", ":"), allow_nan=False)),
        importmap=json.dumps({"imports": imports}),
        viewer=viewer,
    )


def write_viewer(path: PathLike, room: TexturedRoom, record: dict) -> None:
    """Write the viewer's page (:func:`viewer_html`), atomically."""
    write_atomic(path, viewer_html(room, record).encode("utf-8"))
