"""A JAX ray caster for non-central circular panoramas of synthetic scenes.

The paper rendered its dataset with POV-Ray and a custom camera (Section 5.1,
minutes per image). Here every pixel's ray is cast in JAX, jitted and vmapped
over scenes, fast enough to make training data on the fly.

The ray of pixel (u, v) leaves the optical centre ``rc (cos varphi, sin varphi, 0)``
of its column at elevation ``phi`` (paper eq. pluckerray), so every ray of a
column lies in one vertical half-plane and shares its horizontal path. The
renderer exploits that: the walls (O(K)) and the footprints of the boxes (O(B),
2D slab tests) are intersected once per column, and per pixel only the heights
are compared (``z = t tan(phi)`` at horizontal distance ``t``), which makes a
pixel cost O(B) comparisons (:mod:`.raycast`). ``rc = 0`` is the central
equirectangular panorama.

Shading: procedural albedo (``ncjax.synth.materials``), an ambient term darkened
near the room's edges, Lambertian point lights with ``1 / (1 + d^2)`` falloff,
optional hard shadows from the furniture, emissive lamps and windows, then an
exponential tone curve and gamma 2.2. Doors and windows are drawn on the wall
planes, so the layout labels stay exact.

Realistic scenes (``SceneConfig(decor=True)``) add sunlight through the
windows, light panels, decals on the walls and open doors
(``ncjax.synth.render_details``): decals and panels are drawn on the room's
planes, and a ray through an open door goes on into a box-shaped room behind
only once it has met the wall plane inside the doorway, so the labels stay
exact too; what is seen through a doorway is of the class OPENING. That room
looks like a room, as in photographs: skirting boards along its walls' foot,
darker towards its edges, so that its floor line is as plain as the room's own
(a network taught on bare rooms behind doors follows real ones' floor lines).
The renderer compiles these steps only for scenes that have decor.

Not modelled (yet): shadows cast by walls, inter-reflections and specular
surfaces; geometry of windows and skirting boards; views through windows;
furniture other than boxes (no curved shapes, no clutter on tables, nothing on
carpets); floor and table lamps; the capture rig itself; lens and sensor
effects beyond the photometric augmentations of ``ncjax.synth.augment``.
"""

from __future__ import annotations

import dataclasses
import enum
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Key, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama, pixel_to_angles
from .labels import RoomLabels, room_labels
from .materials import Material, material_albedo
from .photoreal import PhotorealConfig, photoreal_image, window_views
from .raycast import box_segment_blocked, cast_columns, nearest_box
from .render_details import (
    ambient_facing,
    ceiling_panels,
    decal_appearance,
    edge_darkening,
    opening_appearance,
    sunlight,
    through_doorway,
    with_skirting,
)
from .rooms import RoomConfig, random_room
from .scene import Scene, SceneConfig, random_scene


class Semantic(enum.IntEnum):
    """Semantic classes of :attr:`Rendering.semantic`."""

    CEILING = 0
    FLOOR = 1
    WALL = 2
    OBJECT = 3
    OPENING = 4  # door or window, and what is seen through an open door


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """Static settings of :func:`render` (hashable: a jit static argument).

    Attributes:
        supersampling: s, odd: each pixel averages s x s rays for the RGB image;
            depth and semantics come from the central ray (the pixel centre), so
            they stay exactly consistent with the labels.
        shadows: cast a shadow ray per pixel and light against the furniture.
        rows_per_chunk: image rows rendered together (bounds memory: per chunk
            the work is rows x W x boxes_per_column).
        boxes_per_column: M, the boxes each column tests, the nearest whose
            footprints its horizontal ray crosses (a farther one is dropped when
            more than M are crossed: :func:`box_overflow` counts such columns).
    """

    supersampling: int = 1
    shadows: bool = False
    rows_per_chunk: int = 16
    boxes_per_column: int = 8

    def __post_init__(self):
        if int(self.supersampling) != self.supersampling or self.supersampling < 1 or self.supersampling % 2 == 0:
            raise ValueError(f"supersampling must be an odd positive integer (1, 3, ...), got {self.supersampling!r}")
        for name in ("rows_per_chunk", "boxes_per_column"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")


class Rendering(eqx.Module):
    """Images of a scene seen by a panorama (all fields traced).

    Attributes:
        rgb: (H, W, 3) colours in [0, 1].
        depth: (H, W) distance from the pixel's optical centre to the first hit
            along its ray, metres.
        semantic: (H, W) :class:`Semantic` classes.
    """

    rgb: Float[Array, "H W 3"]
    depth: Float[Array, "H W"]
    semantic: Int[Array, "H W"]


def _select_material(condition: Array, a: Material, b: Material) -> Material:
    """Per pixel: ``a`` where ``condition`` holds, else ``b`` (fields shaped ``condition.shape + ...``)."""
    return jax.tree.map(
        lambda x, y: jnp.where(condition.reshape(condition.shape + (1,) * (x.ndim - condition.ndim)), x, y), a, b
    )


def _row(scene: Scene, columns: dict, elevation: Float[Array, ""], shadows: bool):
    """Colour, depth and class of the pixels of one row (elevation).

    The decor's steps run only for scenes that have it (a static choice): a basic
    scene's program is the furnished room's alone.
    """
    room, decor = scene.room, scene.decor
    slope = jnp.tan(elevation)
    cotangent = 1.0 / jnp.where(jnp.abs(slope) > 1e-12, slope, 1e-12)
    # Room: the wall of the column, unless the ray leaves through the ceiling or floor first.
    t_wall = columns["t_wall"]
    z_wall = slope * t_wall
    is_ceiling, is_floor = z_wall > room.ceiling_height, z_wall < room.floor_height
    t_room = jnp.where(
        is_ceiling, room.ceiling_height * cotangent, jnp.where(is_floor, room.floor_height * cotangent, t_wall)
    )
    opening = columns["opening"]
    if decor is not None:
        # Open doors are decided on the wall plane (so the layout's edges stay
        # exact); a ray through one goes on into the room behind.
        doorway = columns["doorway"]
        in_doorway = (
            ~is_ceiling & ~is_floor & doorway["aperture"] & (z_wall >= opening["bottom"]) & (z_wall < doorway["lintel"])
        )
        t_behind, behind_upright, in_lining = through_doorway(doorway, slope, cotangent, room.floor_height)
        t_room = jnp.where(in_doorway, t_behind, t_room)
    t_box, box = nearest_box(columns["candidates"], cotangent)
    on_box = t_box < t_room
    t = jnp.where(on_box, t_box, t_room)
    # Points and normals as separate coordinate arrays (structure of arrays):
    # the per-light arithmetic below then vectorises along the row.
    x = columns["origin"][:, 0] + t * columns["direction"][:, 0]
    y = columns["origin"][:, 1] + t * columns["direction"][:, 1]
    z = slope * t
    on_floor_or_ceiling = is_ceiling | is_floor

    # Surface frame, texture coordinates and material of each pixel.
    side_face = on_box & (t_box == box["t_in"])
    wall_normal = columns["wall_normal"]
    normal_x = jnp.where(
        on_box, jnp.where(side_face, box["normal_x"], 0.0), jnp.where(on_floor_or_ceiling, 0.0, wall_normal[:, 0])
    )
    normal_y = jnp.where(
        on_box, jnp.where(side_face, box["normal_y"], 0.0), jnp.where(on_floor_or_ceiling, 0.0, wall_normal[:, 1])
    )
    normal_z = jnp.where(
        on_box, jnp.where(side_face, 0.0, -jnp.sign(slope)), jnp.where(is_ceiling, -1.0, jnp.where(is_floor, 1.0, 0.0))
    )
    offset_x, offset_y = x - box["centre_x"], y - box["centre_y"]
    local_x = offset_x * box["cos"] + offset_y * box["sin"]
    local_y = offset_y * box["cos"] - offset_x * box["sin"]
    facing_x = jnp.abs(box["normal_x"] * box["cos"] + box["normal_y"] * box["sin"]) > 0.5
    box_a = jnp.where(side_face & facing_x, local_y, local_x)
    box_b = jnp.where(side_face, z, local_y)
    height_above_floor = z - room.floor_height
    world_x, world_y = x + room.camera_position[0], y + room.camera_position[1]
    plan_a, plan_b, wall_a, flat = world_x, world_y, columns["along"], on_floor_or_ceiling
    through = None  # with decor, the pixels that see the room behind an open door
    if decor is not None:
        through = in_doorway & ~on_box
        behind_flat = through & ~behind_upright
        behind_up = behind_flat & (slope > 0)
        normal_x = jnp.where(through, jnp.where(behind_flat, 0.0, doorway["normal_x"]), normal_x)
        normal_y = jnp.where(through, jnp.where(behind_flat, 0.0, doorway["normal_y"]), normal_y)
        normal_z = jnp.where(through, jnp.where(behind_up, -1.0, jnp.where(behind_flat, 1.0, 0.0)), normal_z)
        # Floors and ceilings are textured along the room's main axis, as boards and tiles are laid.
        axis = decor.plan_axis
        plan_a, plan_b = world_x * axis[0] + world_y * axis[1], world_y * axis[0] - world_x * axis[1]
        wall_a = jnp.where(through, doorway["texture_a"], wall_a)
        flat = flat | behind_flat
    a = jnp.where(on_box, box_a, jnp.where(flat, plan_a, wall_a))
    b = jnp.where(on_box, box_b, jnp.where(flat, plan_b, height_above_floor))

    def per_pixel(material):
        return jax.tree.map(lambda x: jnp.broadcast_to(x, t.shape + x.shape), material)

    surface = _select_material(
        is_ceiling, per_pixel(scene.ceiling), _select_material(is_floor, per_pixel(scene.floor), per_pixel(scene.walls))
    )
    surface_seed = jnp.where(is_ceiling, 1, jnp.where(is_floor, 2, 3))
    if decor is not None:
        behind = _select_material(
            behind_up,
            per_pixel(scene.ceiling),
            _select_material(behind_flat, per_pixel(decor.next_floor), per_pixel(decor.next_walls)),
        )
        surface = _select_material(through, behind, surface)
        surface_seed = jnp.where(through, jnp.where(behind_up, 4, jnp.where(behind_flat, 5, 6)), surface_seed)
    material = _select_material(on_box, box["material"], surface)
    seed = scene.seed + jnp.where(on_box, 100 + 13 * box["box"], surface_seed)
    albedo = material_albedo(material, seed, a, b, decor=decor is not None)

    # Details on walls: skirting boards, doors and windows (with decor: decals,
    # the lining of an open door's wall thickness, light panels in the ceiling).
    on_wall = ~on_box & ~on_floor_or_ceiling
    in_opening = on_wall & opening["present"] & (z >= opening["bottom"]) & (z <= opening["bottom"] + opening["tall"])
    on_door = in_opening  # the door or window itself, not what is seen through it
    if decor is not None:
        in_opening, on_door = in_opening | through, in_opening & ~through
    opening_albedo, opening_emission = opening_appearance(opening, columns["along"], z)
    skirted = on_wall & ~in_opening
    if decor is not None:
        # The room behind a door has skirting boards too (not in the door's lining): a room, as in photographs.
        skirted = skirted | (through & behind_upright & ~in_lining)
    albedo = with_skirting(albedo, skirted, height_above_floor, scene.skirting_height, scene.skirting_colour)
    other_emission = 0.0
    if decor is not None:
        decal = columns["decal"]
        in_decal = (
            on_wall & ~in_opening & decal["present"] & (z > decal["bottom"]) & (z < decal["bottom"] + decal["tall"])
        )
        decal_albedo = decal_appearance(decal, columns["along"], z, scene.seed + 200 + 7 * decal["index"])
        albedo = jnp.where(in_decal[:, None], decal_albedo, albedo)
    albedo = jnp.where(on_door[:, None], opening_albedo, albedo)
    if decor is not None:
        albedo = jnp.where((through & in_lining)[:, None], opening["frame_colour"], albedo)
        in_panel, panel_rim, panel_emission = ceiling_panels(decor.panels, x, y)
        on_ceiling = ~on_box & is_ceiling
        albedo = jnp.where((on_ceiling & in_panel)[:, None], jnp.where(panel_rim, 0.7, 0.95)[:, None], albedo)
        other_emission = jnp.where(on_ceiling[:, None], panel_emission, 0.0)
    emission = jnp.where(
        on_box[:, None], box["emission"], jnp.where(on_door[:, None], opening_emission, other_emission)
    )

    # Light: ambient darkened near the room's edges, plus point lights (with
    # decor, and the sun; the room behind an open door gets its own share of
    # ambient light only, darkened near its own edges).
    to_edge = jnp.where(on_floor_or_ceiling, t_wall - t, jnp.minimum(height_above_floor, room.ceiling_height - z))
    if decor is not None:
        # The room behind darkens towards its own edges as this one does, on its floor and ceiling to the
        # first upright surface along the ray (a jamb, a side or the back wall).
        to_edge_behind = jnp.where(
            behind_flat, doorway["t_upright"] - t, jnp.minimum(height_above_floor, doorway["ceiling"] - z)
        )
        to_edge = jnp.where(through, to_edge_behind, to_edge)
    occlusion = edge_darkening(to_edge)
    if decor is not None:
        occlusion = jnp.where(through, doorway["light"] * occlusion, occlusion)
    facing = ambient_facing((normal_x, normal_y, normal_z), scene.ambient_direction)
    irradiance = (facing * jnp.where(on_box, 0.85, occlusion))[:, None] * scene.ambient
    irradiance = _add_direct_light(scene, irradiance, (x, y, z), (normal_x, normal_y, normal_z), through, shadows)
    radiance = albedo * irradiance + emission
    rgb = tone_curve(radiance)
    semantic = jnp.where(
        on_box,
        Semantic.OBJECT,
        jnp.where(
            is_ceiling,
            Semantic.CEILING,
            jnp.where(is_floor, Semantic.FLOOR, jnp.where(in_opening, Semantic.OPENING, Semantic.WALL)),
        ),
    )
    return rgb, t / jnp.cos(elevation), semantic.astype(jnp.int32)


def _add_direct_light(scene: Scene, irradiance, point, normal, through, shadows: bool):
    """``irradiance`` plus the light of the point lights (each optionally shadowed by the furniture) and, with
    decor, of the sun at the pixels of a row: ``point`` and ``normal`` are their coordinate arrays ``(x, y, z)``;
    the room behind an open door (``through``, None without decor) gets none of it."""
    boxes, decor = scene.boxes, scene.decor
    x, y, z = point
    normal_x, normal_y, normal_z = normal
    casts_shadow = jnp.all(boxes.emission == 0, -1) & boxes.mask
    if decor is not None:
        sun = sunlight(decor.sun, point, normal)
        irradiance = irradiance + jnp.where(through[:, None], 0.0, sun)
        # Thin plates (fan blades, carpets) cast no shadow: from a point light, a fan's
        # blades would throw huge black shadows over the ceiling that real, softer light does not.
        casts_shadow = casts_shadow & (boxes.half_size[:, 2] > 0.01)
    lights = scene.lights
    for index in range(lights.position.shape[0]):
        light = lights.position[index]
        dx, dy, dz = light[0] - x, light[1] - y, light[2] - z
        distance2 = dx * dx + dy * dy + dz * dz
        cosine = jnp.maximum(normal_x * dx + normal_y * dy + normal_z * dz, 0.0) * jax.lax.rsqrt(distance2)
        received = cosine / (1.0 + distance2) * lights.mask[index]
        if decor is not None:
            received = jnp.where(through, 0.0, received)
        if shadows:
            start = jnp.stack([x + 1e-3 * normal_x, y + 1e-3 * normal_y, z + 1e-3 * normal_z], -1)
            blocked = jax.vmap(box_segment_blocked, in_axes=(0, None, None, None))(start, light, boxes, casts_shadow)
            received = jnp.where(blocked, 0.0, received)
        irradiance = irradiance + received[:, None] * lights.colour[index]
    return irradiance


def render(scene: Scene, cam: NonCentralPanorama, config: RenderConfig = RenderConfig()) -> Rendering:
    """Ray-cast the panorama of ``scene`` seen by ``cam`` (paper Section 3 camera, Section 5.1 data).

    Args:
        scene: one scene (camera frame); its room's ``rc`` is NOT used: ``cam.rc`` is,
            as in :func:`~ncjax.synth.room_labels` (use ``scene.room.camera(W, H)``).
        cam: the panorama (static width W and height H; traced rc and fields of view).
        config: static settings (supersampling, shadows).

    Returns:
        A :class:`Rendering` of shape (H, W). Jit with ``config`` static and vmap over scenes.
    """
    s = config.supersampling
    fine = NonCentralPanorama(cam.width * s, cam.height * s, cam.rc, cam.fov_horizontal, cam.fov_vertical)
    columns = cast_columns(scene, fine, min(config.boxes_per_column, scene.boxes.mask.shape[-1]))
    _, elevation = pixel_to_angles(fine, 0.0, jnp.arange(fine.height, dtype=columns["t_wall"].dtype))
    rgb, depth, semantic = jax.lax.map(
        lambda e: _row(scene, columns, e, config.shadows), elevation, batch_size=config.rows_per_chunk * s
    )
    rgb = rgb.reshape(cam.height, s, cam.width, s, 3).mean(axis=(1, 3))
    centre = s // 2
    return Rendering(
        rgb=rgb,
        depth=depth.reshape(cam.height, s, cam.width, s)[:, centre, :, centre],
        semantic=semantic.reshape(cam.height, s, cam.width, s)[:, centre, :, centre],
    )


def box_overflow(scene: Scene, cam: NonCentralPanorama, config: RenderConfig = RenderConfig()) -> Bool[Array, " W"]:
    """Columns whose ray crosses more box footprints than ``config.boxes_per_column``
    (where :func:`render` may miss a box behind the nearest ones)."""
    return cast_columns(scene, cam, min(config.boxes_per_column, scene.boxes.mask.shape[-1]))["overflow"]


@dataclasses.dataclass(frozen=True)
class SynthConfig:
    """Static configuration of :func:`synthesize`: room, scene and render settings and the image size.

    ``photoreal``: None, the RGB image is the ray caster's (``render``); else its settings
    (:class:`~ncjax.synth.photoreal.PhotorealConfig`): the RGB image is the scene path-traced and photographed,
    the depth and the semantics still the ray caster's.
    """

    room: RoomConfig = RoomConfig()
    scene: SceneConfig = SceneConfig()
    render: RenderConfig = RenderConfig()
    width: int = 1024
    height: int = 512
    photoreal: PhotorealConfig | None = None

    def __post_init__(self):
        if int(self.width) != self.width or self.width < 8 or int(self.height) != self.height or self.height < 4:
            raise ValueError(f"image size must be at least 4 x 8 pixels (H x W), got {self.height} x {self.width}")
        scale = 1 if self.photoreal is None else self.photoreal.trace_scale
        if self.width % scale or self.height % scale:
            raise ValueError(f"photoreal.trace_scale {scale} must divide the image size {self.height} x {self.width}")


def synthesize_scene(key: PRNGKeyArray, config: SynthConfig = SynthConfig()) -> tuple[Scene, RoomLabels]:
    """A random furnished room and its exact labels (:func:`~ncjax.synth.room_labels`:
    furniture ignored, the layout a network must predict)."""
    key_room, key_scene = jax.random.split(key)
    room = random_room(key_room, config.room)
    # rc to 0.1 mm, so that the file names of the dataset (``..._R06101``) hold it exactly.
    room = eqx.tree_at(lambda r: r.rc, room, jnp.round(room.rc * 1e4) / 1e4)
    scene = random_scene(key_scene, room, config.scene)
    return scene, room_labels(room, room.camera(config.width, config.height))


def synthesize(key: PRNGKeyArray, config: SynthConfig = SynthConfig()) -> tuple[Scene, Rendering, RoomLabels]:
    """One synthetic training sample: a random furnished room, its panorama and its exact labels.

    Jit with ``config`` static, vmap over keys; or use :func:`synthesize_batch`,
    which compiles much faster.
    """
    scene, labels = synthesize_scene(key, config)
    rendering = render(scene, scene.room.camera(config.width, config.height), config.render)
    if config.photoreal is not None:
        rendering = eqx.tree_at(lambda r: r.rgb, rendering, photoreal_rgb(key, scene, config, window_views()))
    return scene, rendering, labels


# The ray caster's exposure and display gamma (:func:`tone_curve`).
_EXPOSURE, _GAMMA = 1.5, 2.2


def tone_curve(radiance: Float[Array, "*shape 3"]) -> Float[Array, "*shape 3"]:
    """The ray caster's colours from its radiance: an exponential tone curve, then gamma 2.2, in [0, 1)."""
    return (1.0 - jnp.exp(-_EXPOSURE * radiance)) ** (1.0 / _GAMMA)


def radiance_from_colours(rgb: Float[ArrayLike, "*shape 3"]) -> Float[Array, "*shape 3"]:
    """The radiance behind the ray caster's colours: the inverse of :func:`tone_curve` (a colour of 1, which the
    curve never reaches, taken as just below it)."""
    return -jnp.log(jnp.clip(1.0 - jnp.asarray(rgb) ** _GAMMA, 1e-6, 1.0)) / _EXPOSURE


# the photoreal image's random stream: fold_in(key, 1), apart from split(key), the room's and the scene's
_PHOTOREAL_STREAM = 1


def photoreal_rgb(
    key: PRNGKeyArray, scene: Scene, config: SynthConfig, views: Float[Array, "N He We 3"]
) -> Float[Array, "H W 3"]:
    """The RGB image of the sample of ``key`` (:func:`synthesize`'s) and its ``scene`` with ``config.photoreal``:
    :func:`~ncjax.synth.photoreal.photoreal_image`, its windows showing ``views``
    (:func:`~ncjax.synth.photoreal.window_views`)."""
    cam = scene.room.camera(config.width, config.height)
    return photoreal_image(jax.random.fold_in(key, _PHOTOREAL_STREAM), scene, cam, views, config.photoreal)


# Scene generation is branchy code whose run time is negligible next to
# rendering; XLA's backend optimisations cost it minutes of compilation for
# nothing, so it is compiled without them.
_FAST_COMPILE = {"xla_backend_optimization_level": 0}


@functools.cache
def _batched_scenes(config: SynthConfig):
    return jax.jit(jax.vmap(lambda key: synthesize_scene(key, config)), compiler_options=_FAST_COMPILE)


@functools.cache
def _batched_render(config: SynthConfig):
    return jax.jit(jax.vmap(lambda scene: render(scene, scene.room.camera(config.width, config.height), config.render)))


@functools.cache
def _batched_photoreal(config: SynthConfig):
    return jax.jit(jax.vmap(lambda key, scene, views: photoreal_rgb(key, scene, config, views), in_axes=(0, 0, None)))


def synthesize_batch(
    keys: Key[Array, " N"], config: SynthConfig = SynthConfig()
) -> tuple[Scene, Rendering, RoomLabels]:
    """:func:`synthesize` for a batch of keys (leading axis N), two cached jitted calls (three with photoreal).

    Compiled once per ``config`` and batch size; keep the batch size fixed
    (pad the last batch) to avoid recompiling.
    """
    scenes, labels = _batched_scenes(config)(keys)
    renderings = _batched_render(config)(scenes)
    if config.photoreal is not None:  # the views are an argument, not a constant of the program
        rgb = _batched_photoreal(config)(keys, scenes, window_views())
        renderings = eqx.tree_at(lambda r: r.rgb, renderings, rgb)
    return scenes, renderings, labels
