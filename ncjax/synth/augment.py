"""Photometric augmentations of panoramas for training (pure jnp, jit/vmap-able).

Every function takes one RGB image (H, W, 3) float in [0, 1] (docs/design.md section 5)
and returns one of the same shape, clipped to [0, 1] (a batch is a ``jax.vmap``);
random ones take a ``jax.random`` key first. They imitate what a real camera does
to the scene the renderer draws: exposure, gamma and colour cast, optical blur and
vignetting, sensor noise, the seams and the uncovered poles of a panorama stitched
from several lenses, and JPEG compression. The geometry is untouched (at most the
seams' shift of a pixel or two, as in real stitching), so the labels stay those of
the scene. Real non-central captures are often grey, so greyscale is among them.
Horizontal operations wrap around: a panorama's left and right edges meet.
The greyscale and the blur are the network's own (:mod:`ncjax.network.denoise`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray, Real

from ..network.denoise import gaussian_blur, to_greyscale


def adjust_exposure(image: Float[Array, "H W 3"], factor: Float[ArrayLike, "*#S"]) -> Float[Array, "H W 3"]:
    """Scale the linear intensities (the image is gamma 2.2 encoded) by ``factor``
    (a scalar, or per pixel: any shape that broadcasts against the image)."""
    return jnp.clip(image * factor ** (1 / 2.2), 0.0, 1.0)


def adjust_gamma(image: Float[Array, "H W 3"], gamma: Float[ArrayLike, ""]) -> Float[Array, "H W 3"]:
    """``image ** gamma``."""
    return jnp.clip(image, 0.0, 1.0) ** gamma


def white_balance(image: Float[Array, "H W 3"], gains: Float[ArrayLike, 3]) -> Float[Array, "H W 3"]:
    """Per-channel gains (a colour cast)."""
    return jnp.clip(image * gains, 0.0, 1.0)


def add_sensor_noise(
    key: PRNGKeyArray, image: Float[Array, "H W 3"], read_sigma: Float[ArrayLike, ""], shot_sigma: Float[ArrayLike, ""]
) -> Float[Array, "H W 3"]:
    """Gaussian noise whose variance grows with the intensity (read + shot noise)."""
    sigma = jnp.sqrt(read_sigma**2 + shot_sigma**2 * jnp.clip(image, 0.0, 1.0))
    return jnp.clip(image + sigma * jax.random.normal(key, image.shape), 0.0, 1.0)


def vignetting_factor(
    height: int,
    width: int,
    strength: Float[ArrayLike, ""],
    lenses: Real[ArrayLike, ""],
    phase: Float[ArrayLike, ""],
    elevation_strength: Float[ArrayLike, ""],
) -> Float[Array, "H W"]:
    """The linear light falloff of a panorama stitched from ``lenses`` lenses round the horizon.

    Imitates vignetting: each lens passes less light off its axis (the cos^4 law
    and the lens barrel), and the stitched panorama darkens towards the borders
    between the lenses. For an equirectangular panorama this is periodic in the
    columns: the angle to the nearest lens axis, scaled so that half-way between
    two axes is 90 degrees, enters a cos^4 falloff. Towards the poles, which the
    lenses see far off-axis too, a milder ``1 - elevation_strength sin^2(elevation)``.

    Args:
        height, width: the panorama's size.
        strength: the azimuthal falloff's depth: the factor is ``1 - strength``
            half-way between two lens axes.
        lenses: number of lenses (their axes ``2 pi / lenses`` apart in azimuth).
        phase: azimuth of one lens axis in radians (column ``u`` is at azimuth
            ``2 pi (u + 0.5) / width``).
        elevation_strength: the factor is ``1 - elevation_strength`` at the poles.

    Returns:
        The factor in (0, 1] per pixel, 1 on the lens axes at the horizon.
    """
    azimuth = 2 * jnp.pi * (jnp.arange(width) + 0.5) / width
    elevation = jnp.pi / 2 - jnp.pi * (jnp.arange(height) + 0.5) / height
    # cos^2(lenses * offset / 2) = (1 + cos(lenses * offset)) / 2 is periodic in the lenses without a modulo
    half_angle_cos2 = (1 + jnp.cos(lenses * (azimuth - phase))) / 2
    horizontal = 1 - strength * (1 - half_angle_cos2**2)
    vertical = 1 - elevation_strength * jnp.sin(elevation) ** 2
    return vertical[:, None] * horizontal[None, :]


def vignette(
    image: Float[Array, "H W 3"],
    strength: Float[ArrayLike, ""],
    lenses: Real[ArrayLike, ""],
    phase: Float[ArrayLike, ""],
    elevation_strength: Float[ArrayLike, ""],
) -> Float[Array, "H W 3"]:
    """Darken the panorama by :func:`vignetting_factor` (applied to the linear intensities).

    Imitates the vignetting of the lenses of a multi-lens panoramic camera.
    """
    height, width = image.shape[:2]
    factor = vignetting_factor(height, width, strength, lenses, phase, elevation_strength)
    return adjust_exposure(image, factor[..., None])


# ITU-T T.81 Annex K quantisation tables (luminance, chrominance), rows of the 8 x 8 block
_JPEG_LUMA_TABLE = np.array(
    [
        [16, 11, 10, 16, 24, 40, 51, 61],
        [12, 12, 14, 19, 26, 58, 60, 55],
        [14, 13, 16, 24, 40, 57, 69, 56],
        [14, 17, 22, 29, 51, 87, 80, 62],
        [18, 22, 37, 56, 68, 109, 103, 77],
        [24, 35, 55, 64, 81, 104, 113, 92],
        [49, 64, 78, 87, 103, 121, 120, 101],
        [72, 92, 95, 98, 112, 100, 103, 99],
    ],
    np.float32,
)
_JPEG_CHROMA_TABLE = np.array(
    [
        [17, 18, 24, 47, 99, 99, 99, 99],
        [18, 21, 26, 66, 99, 99, 99, 99],
        [24, 26, 56, 99, 99, 99, 99, 99],
        [47, 66, 99, 99, 99, 99, 99, 99],
        [99, 99, 99, 99, 99, 99, 99, 99],
        [99, 99, 99, 99, 99, 99, 99, 99],
        [99, 99, 99, 99, 99, 99, 99, 99],
        [99, 99, 99, 99, 99, 99, 99, 99],
    ],
    np.float32,
)
# JFIF's RGB -> YCbCr (without the 128 offset of the chroma, which the level shift before the DCT removes again)
_RGB_TO_YCBCR = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]], np.float32)
_YCBCR_TO_RGB = np.linalg.inv(_RGB_TO_YCBCR.astype(np.float64)).astype(np.float32)


def _dct_matrix(n: int = 8) -> np.ndarray:
    """The orthonormal DCT-II matrix: ``coefficients = M @ samples``."""
    frequency, sample = np.arange(n)[:, None], np.arange(n)[None, :]
    matrix = np.sqrt(2 / n) * np.cos(np.pi * (2 * sample + 1) * frequency / (2 * n))
    matrix[0] /= np.sqrt(2)
    return matrix.astype(np.float32)


_DCT = _dct_matrix()
# float32 products in full precision: GPUs would otherwise use TF32, whose error is a grey level at 255
_EXACT = jax.lax.Precision.HIGHEST


def block_dct(plane: Float[Array, "H W"]) -> Float[Array, "H W"]:
    """Orthonormal 2-D DCT-II of each 8 x 8 block (H and W multiples of 8), as JPEG does.

    Block ``(i, j)``'s coefficient ``(a, b)`` (vertical, horizontal frequency) is
    at pixel ``(8 i + a, 8 j + b)``.
    """
    height, width = plane.shape
    blocks = plane.reshape(height // 8, 8, width // 8, 8)
    coefficients = jnp.einsum("ax,ixjy,by->iajb", _DCT, blocks, _DCT, precision=_EXACT)
    return coefficients.reshape(height, width)


def block_idct(coefficients: Float[Array, "H W"]) -> Float[Array, "H W"]:
    """The inverse of :func:`block_dct`."""
    height, width = coefficients.shape
    blocks = coefficients.reshape(height // 8, 8, width // 8, 8)
    return jnp.einsum("ax,iajb,by->ixjy", _DCT, blocks, _DCT, precision=_EXACT).reshape(height, width)


def jpeg_quantisation_table(base: Float[ArrayLike, "8 8"], quality: Real[ArrayLike, ""]) -> Float[Array, "8 8"]:
    """libjpeg's scaling of a quantisation table to a quality in [1, 100] (rounded to an integer).

    Quality 50 gives ``base``, 100 all ones (no quantisation beyond rounding), lower
    qualities coarser steps, up to 255 (baseline JPEG's limit).
    """
    quality = jnp.round(jnp.clip(quality, 1, 100))
    scale = jnp.where(quality < 50, jnp.floor(5000 / quality), 200 - 2 * quality)
    return jnp.clip(jnp.floor((jnp.asarray(base) * scale + 50) / 100), 1, 255)


def _quantise_plane(plane: Float[Array, "H W"], table: Float[Array, "8 8"]) -> Float[Array, "H W"]:
    """DCT, quantisation to multiples of ``table`` per coefficient, dequantisation and inverse DCT."""
    steps = jnp.tile(table, (plane.shape[0] // 8, plane.shape[1] // 8))
    return block_idct(jnp.round(block_dct(plane) / steps) * steps)


def jpeg_compress(
    image: Float[Array, "H W 3"], quality: Real[ArrayLike, ""], chroma_subsampling: bool = True
) -> Float[Array, "H W 3"]:
    """Compress and decompress the image as a baseline JPEG of ``quality`` (1 to 100) does.

    Imitates the lossy compression of the camera's or the web's JPEG files: the
    image in YCbCr, each 8 x 8 block's DCT coefficients rounded to multiples of
    libjpeg's quality-scaled tables (ringing near edges, smeared colours, and at low
    quality visible blocks), decoded to 8-bit values. The image is padded with its
    edge values to whole blocks and cropped back.

    Args:
        image: RGB in [0, 1].
        quality: the JPEG quality (may be traced).
        chroma_subsampling: halve the chroma's resolution in both directions (4:2:0,
            what cameras write; static): 2 x 2 means when encoding, bilinear
            interpolation when decoding (libjpeg's "fancy" upsampling).

    Returns:
        The decoded image, multiples of 1/255.
    """
    height, width = image.shape[:2]
    block = 16 if chroma_subsampling else 8
    padded = jnp.pad(image, ((0, -height % block), (0, -width % block), (0, 0)), mode="edge")
    # the level shift by 128 centres the samples before the DCT; chroma is already centred
    ycbcr = jnp.matmul(255 * padded, _RGB_TO_YCBCR.T, precision=_EXACT) - jnp.array([128.0, 0.0, 0.0])
    luma = _quantise_plane(ycbcr[..., 0], jpeg_quantisation_table(_JPEG_LUMA_TABLE, quality))
    chroma_table = jpeg_quantisation_table(_JPEG_CHROMA_TABLE, quality)
    chroma = []
    for channel in (1, 2):
        plane = ycbcr[..., channel]
        if chroma_subsampling:
            half = plane.reshape(plane.shape[0] // 2, 2, plane.shape[1] // 2, 2).mean(axis=(1, 3))
            plane = jax.image.resize(_quantise_plane(half, chroma_table), plane.shape, "linear")
        else:
            plane = _quantise_plane(plane, chroma_table)
        chroma.append(plane)
    decoded = jnp.stack([luma + 128.0, *chroma], axis=-1)
    rgb = jnp.matmul(decoded, _YCBCR_TO_RGB.T, precision=_EXACT)
    return jnp.clip(jnp.round(rgb), 0, 255)[:height, :width] / 255


def black_bands(
    image: Float[Array, "H W 3"], top: Real[ArrayLike, ""], bottom: Real[ArrayLike, ""]
) -> Float[Array, "H W 3"]:
    """Black out the first ``top`` and the last ``bottom`` rows (rounded up; may be traced).

    Imitates panoramas from cameras whose lenses do not reach the zenith and the
    nadir: the stitcher leaves those rows black.
    """
    rows = jnp.arange(image.shape[0])[:, None, None]
    covered = (rows >= jnp.ceil(top)) & (rows < image.shape[0] - jnp.ceil(bottom))
    return jnp.where(covered, image, 0.0)


def stitching_seams(
    image: Float[Array, "H W 3"],
    columns: Float[ArrayLike, " K"],
    gains: Float[ArrayLike, "K 3"],
    shifts: Float[ArrayLike, " K"],
    blend: Float[ArrayLike, ""],
    extent: Float[ArrayLike, ""],
) -> Float[Array, "H W 3"]:
    """Seams where the images of two lenses meet in a stitched panorama.

    Imitates the residual exposure / white balance difference and the parallax
    misalignment of the lenses: right of each seam column the image is multiplied by
    per-channel ``gains`` and moved down by ``shifts`` rows (fractional, linear
    interpolation, edge rows repeated). The step is blended over ``blend`` columns
    centred on the seam and fades back to nothing over ``extent`` columns, as a
    stitcher's gain compensation evens the exposure out away from the seams; columns
    further from every seam are returned unchanged. A seam with gain 1 and shift 0
    does nothing.

    Args:
        image: RGB in [0, 1].
        columns: the seams' positions (columns, fractional, wrapping around).
        gains: per seam, the right side's gain per channel.
        shifts: per seam, the right side's vertical shift in rows (keep it to a
            pixel or two: the labels stay the scene's).
        blend: width of the blend across each seam in columns (> 0).
        extent: columns right of the seam over which the step fades out (> 0).
    """
    height, width = image.shape[:2]
    columns, gains, shifts = jnp.asarray(columns), jnp.asarray(gains), jnp.asarray(shifts)
    # signed distance of each column from each seam, wrapped to [-width / 2, width / 2)
    distance = (jnp.arange(width)[None, :] - columns[:, None] + width / 2) % width - width / 2
    rise = jnp.clip(distance / jnp.maximum(blend, 1e-3) + 0.5, 0.0, 1.0)
    weight = rise * jnp.clip(1.0 - distance / jnp.maximum(extent, 1e-3), 0.0, 1.0)  # (K, W), 0 far from the seams
    column_gain = jnp.exp(weight.T @ jnp.log(gains))  # (W, 3)
    source_row = jnp.arange(height)[:, None] - (weight.T @ shifts)[None, :]  # (H, W)
    below = jnp.floor(source_row)
    fraction = (source_row - below)[..., None]
    below = jnp.clip(below.astype(jnp.int32), 0, height - 1)
    above = jnp.clip(below + 1, 0, height - 1)

    def rows(index):
        return jnp.take_along_axis(image, jnp.broadcast_to(index[..., None], image.shape), axis=0)

    shifted = rows(below) * (1 - fraction) + rows(above) * fraction
    return jnp.clip(shifted * column_gain, 0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Ranges and probabilities of :func:`random_augment` (static, hashable).

    Each range ``(low, high)`` is drawn uniformly unless said otherwise; each
    effect with a probability is applied with it, independently of the others.

    Attributes:
        exposure: factor on the linear intensities, drawn log-uniformly.
        gamma: exponent of the encoded intensities.
        white_balance: gain of each channel (a colour cast).
        read_noise: standard deviation of the intensity-independent sensor noise.
        shot_noise: standard deviation of the sensor noise at intensity 1 (grows as its square root).
        blur_sigma: standard deviation of the optical blur in pixels.
        blur_probability: probability of the blur.
        greyscale_probability: probability of replacing the colours by their luma.
        vignetting_probability: probability of the lenses' vignetting.
        vignetting_strength: the vignetting's darkening half-way between two lenses (linear).
        vignetting_lenses: number of lenses round the horizon (integers, both included).
        vignetting_elevation_strength: the vignetting's darkening at the poles (linear).
        jpeg_probability: probability of JPEG compression.
        jpeg_quality: JPEG quality (1 to 100).
        jpeg_chroma_subsampling: JPEG at half the chroma resolution (4:2:0), as cameras write it.
        band_probability: probability of a black band at the top, and independently at the bottom.
        band_height: height of a black band as a fraction of the image height.
        seam_probability: probability of stitching seams.
        seam_count: the most seams (at least one when there are seams).
        seam_exposure: a seam's exposure step (factor on the right side).
        seam_white_balance: a seam's extra gain per channel.
        seam_shift: a seam's vertical shift of the right side in pixels.
        seam_blend: width of a seam's blend as a fraction of the image width.
        seam_extent: how far right of a seam its step fades out, as a fraction of the image width.
    """

    exposure: tuple[float, float] = (0.5, 2.0)
    gamma: tuple[float, float] = (0.8, 1.25)
    white_balance: tuple[float, float] = (0.85, 1.15)
    read_noise: tuple[float, float] = (0.0, 0.02)
    shot_noise: tuple[float, float] = (0.0, 0.04)
    blur_sigma: tuple[float, float] = (0.3, 1.2)
    blur_probability: float = 0.3
    greyscale_probability: float = 0.2
    vignetting_probability: float = 0.5
    vignetting_strength: tuple[float, float] = (0.1, 0.5)
    vignetting_lenses: tuple[int, int] = (2, 6)
    vignetting_elevation_strength: tuple[float, float] = (0.0, 0.3)
    jpeg_probability: float = 0.5
    jpeg_quality: tuple[float, float] = (20.0, 95.0)
    jpeg_chroma_subsampling: bool = True
    band_probability: float = 0.2
    band_height: tuple[float, float] = (0.0, 0.12)
    seam_probability: float = 0.3
    seam_count: int = 3
    seam_exposure: tuple[float, float] = (0.85, 1.15)
    seam_white_balance: tuple[float, float] = (0.96, 1.04)
    seam_shift: tuple[float, float] = (-2.0, 2.0)
    seam_blend: tuple[float, float] = (0.002, 0.02)
    seam_extent: tuple[float, float] = (0.05, 0.25)

    @classmethod
    def from_dict(cls, values: dict) -> AugmentConfig:
        """The configuration ``dataclasses.asdict`` gave, after JSON (which turns the ranges into lists)."""
        return cls(**{name: tuple(value) if isinstance(value, list) else value for name, value in values.items()})


def _between(u: Float[ArrayLike, "*S"], bounds: tuple[float, float]) -> Float[Array, "*S"]:
    """Uniforms in [0, 1) mapped to ``bounds``."""
    return bounds[0] + jnp.asarray(u) * (bounds[1] - bounds[0])


def random_augment(
    key: PRNGKeyArray, image: Float[Array, "H W 3"], config: AugmentConfig = AugmentConfig()
) -> Float[Array, "H W 3"]:
    """A random camera's rendition of the image, with parameters drawn from ``config``.

    In the order a camera works: vignetting (sometimes); exposure, gamma and white
    balance; blur (sometimes); stitching seams (sometimes); greyscale (sometimes);
    sensor noise; black bands at the top and the bottom (each sometimes); JPEG
    compression (sometimes). Every effect is computed and selected with ``jnp.where``
    from a fixed number of uniforms, so the function compiles once per image shape
    and configuration.
    """
    height, width = image.shape[:2]
    key_noise, key_parameters, key_vignetting, key_seams, key_bands, key_jpeg = jax.random.split(key, 6)
    u = jax.random.uniform(key_parameters, (10,))

    v = jax.random.uniform(key_vignetting, (5,))
    low_lenses, high_lenses = config.vignetting_lenses
    lenses = jnp.minimum(low_lenses + jnp.floor(v[1] * (high_lenses - low_lenses + 1)), high_lenses)
    vignetted = vignette(
        image,
        _between(v[2], config.vignetting_strength),
        lenses,
        2 * jnp.pi * v[3],
        _between(v[4], config.vignetting_elevation_strength),
    )
    image = jnp.where(v[0] < config.vignetting_probability, vignetted, image)

    # Exposure is drawn log-uniformly: halving and doubling are equally likely.
    log_low, log_high = jnp.log(config.exposure[0]), jnp.log(config.exposure[1])
    image = adjust_exposure(image, jnp.exp(log_low + u[0] * (log_high - log_low)))
    image = adjust_gamma(image, _between(u[1], config.gamma))
    image = white_balance(image, _between(u[2:5], config.white_balance))
    image = jnp.where(u[5] < config.blur_probability, gaussian_blur(image, _between(u[6], config.blur_sigma)), image)

    n = config.seam_count
    s = jax.random.uniform(key_seams, (4 + 6 * n,))
    positions, exposures, shifts = s[4 : 4 + n], s[4 + n : 4 + 2 * n], s[4 + 2 * n : 4 + 3 * n]
    gains = _between(exposures[:, None], config.seam_exposure) * _between(
        s[4 + 3 * n :].reshape(n, 3), config.seam_white_balance
    )
    # Seams beyond a random count (1 to seam_count) are neutral: gain 1, shift 0.
    present = jnp.arange(n) < 1 + jnp.floor(s[1] * n)
    seamed = stitching_seams(
        image,
        width * positions,
        jnp.where(present[:, None], gains, 1.0),
        jnp.where(present, _between(shifts, config.seam_shift), 0.0),
        width * _between(s[2], config.seam_blend),
        width * _between(s[3], config.seam_extent),
    )
    image = jnp.where(s[0] < config.seam_probability, seamed, image)

    image = jnp.where(u[7] < config.greyscale_probability, to_greyscale(image), image)
    image = add_sensor_noise(key_noise, image, _between(u[8], config.read_noise), _between(u[9], config.shot_noise))

    b = jax.random.uniform(key_bands, (4,))
    top = jnp.where(b[0] < config.band_probability, jnp.ceil(height * _between(b[1], config.band_height)), 0)
    bottom = jnp.where(b[2] < config.band_probability, jnp.ceil(height * _between(b[3], config.band_height)), 0)
    image = black_bands(image, top, bottom)

    j = jax.random.uniform(key_jpeg, (2,))
    compressed = jpeg_compress(image, _between(j[1], config.jpeg_quality), config.jpeg_chroma_subsampling)
    return jnp.where(j[0] < config.jpeg_probability, compressed, image)
