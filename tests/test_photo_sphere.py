"""Panoramas that cover the full circle but not the poles: their XMP GPano place, and the padding to the full sphere."""

import re
import struct

import cv2
import numpy as np
import pytest

from ncjax.io.images import (
    PanoramaError,
    PanoramaPaddedWarning,
    PanoramaResizeWarning,
    read_panorama,
    read_panorama_file,
)
from ncjax.io.photo_sphere import (
    XMP_GPANO,
    SphereCrop,
    SphereCropError,
    gpano_crop,
    gpano_fields,
    gpano_packet,
    pad_to_sphere,
    photographed_pixels,
    png_compressed_xmp,
    png_with_xmp,
    vertical_coverage,
)


def gpano_xmp(fields: dict, elements: bool = False) -> bytes:
    """An XMP packet holding ``fields`` in the GPano namespace, as attributes or as elements."""
    if elements:
        body = "".join(f"<GPano:{k}>{v}</GPano:{k}>" for k, v in fields.items())
        description = f'<rdf:Description rdf:about="">{body}</rdf:Description>'
    else:
        attributes = " ".join(f'GPano:{k}="{v}"' for k, v in fields.items())
        description = f'<rdf:Description rdf:about="" {attributes}/>'
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#" '
        f'xmlns:GPano="http://ns.google.com/photos/1.0/panorama/">{description}</rdf:RDF></x:xmpmeta>'
    ).encode()


def jpeg_with_xmp(rgb: np.ndarray, xmp: bytes) -> bytes:
    """A JPEG of ``rgb`` with ``xmp`` in an APP1 segment right after SOI, as cameras write it."""
    jpeg = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    payload = b"http://ns.adobe.com/xap/1.0/\x00" + xmp
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


def sphere_fields(full=(2048, 1024), crop=(2048, 640), left=0, top=192, **more):
    return {
        "ProjectionType": "equirectangular",
        "FullPanoWidthPixels": full[0],
        "FullPanoHeightPixels": full[1],
        "CroppedAreaImageWidthPixels": crop[0],
        "CroppedAreaImageHeightPixels": crop[1],
        "CroppedAreaLeftPixels": left,
        "CroppedAreaTopPixels": top,
        **more,
    }


def test_gpano_fields_read_attributes_and_elements_alike():
    fields = sphere_fields()
    for elements in (False, True):
        read = gpano_fields(b"\xff\xd8 some bytes " + gpano_xmp(fields, elements) + b" more bytes")
        assert {k: read[k] for k in fields} == {k: str(v) for k, v in fields.items()}
    assert gpano_fields(b'no packet GPano:FullPanoWidthPixels="2048"') == {}  # only inside an XMP packet
    # another prefix bound to the namespace, an element with attributes, in the second of two packets
    other = (
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/"></x:xmpmeta><x:xmpmeta xmlns:x="adobe:ns:meta/">'
        b'<rdf:Description xmlns:gp="http://ns.google.com/photos/1.0/panorama/" gp:FullPanoWidthPixels="4096">'
        b'<gp:CroppedAreaTopPixels rdf:datatype="int">12</gp:CroppedAreaTopPixels></rdf:Description></x:xmpmeta>'
    )
    assert gpano_fields(other) == {"FullPanoWidthPixels": "4096", "CroppedAreaTopPixels": "12"}


@pytest.mark.parametrize("compressed", [False, True], ids=["iTXt", "compressed iTXt"])
def test_gpano_packet_is_read_back_as_its_crop(compressed):
    crop = SphereCrop(4096, 2048, 300, 4096, 1200, XMP_GPANO)
    png = png_with_xmp(np.zeros((4, 8, 3), np.uint8), gpano_packet(crop), compressed)
    assert (gpano_packet(crop) in png) != compressed  # compressed, the packet is not in the file's bytes
    assert cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED).shape == (4, 8, 3)  # a valid PNG
    assert gpano_crop(gpano_fields(png), 4096, 1200) == crop


def test_a_compressed_chunk_that_is_not_xmp_or_does_not_decompress_is_left_out():
    crop = SphereCrop(4096, 2048, 300, 4096, 1200, XMP_GPANO)
    png = png_with_xmp(np.zeros((4, 8, 3), np.uint8), gpano_packet(crop), compressed=True)
    assert png_compressed_xmp(png) == [gpano_packet(crop)]
    assert png_compressed_xmp(png.replace(b"XML:com.adobe.xmp", b"XML:com.adobe.xmq")) == []
    start = png.index(b"XML:com.adobe.xmp") + len(b"XML:com.adobe.xmp") + 5
    broken = png[:start] + b"\xff" * 8 + png[start + 8 :]  # the zlib stream's head damaged
    assert png_compressed_xmp(broken) == [] and gpano_fields(broken) == {}
    assert png_compressed_xmp(b"\xff\xd8" + gpano_packet(crop)) == []  # a JPEG: its packets are in its bytes
    bomb = png_with_xmp(np.zeros((4, 8, 3), np.uint8), b"<x:xmpmeta" + bytes(64 << 20) + b"</x:xmpmeta>", True)
    assert len(bomb) < 200_000 and png_compressed_xmp(bomb) == []  # 64 MB inflated from under 200 kB: left out


def test_gpano_crop_is_scaled_to_a_file_resized_after_its_metadata():
    crop = gpano_crop({k: str(v) for k, v in sphere_fields().items()}, 2048, 640)
    assert crop == (2048, 1024, 192, 2048, 640, XMP_GPANO)
    # a turn about the vertical (CroppedAreaLeftPixels of a full circle) changes no layout: the columns stay the file's
    half = gpano_crop({k: str(v) for k, v in sphere_fields(left=100).items()}, 1024, 320)
    assert half == (1024, 512, 96, 1024, 320, XMP_GPANO)
    # pixels not quite square after a resize: the rows the crop spans in the full panorama, not the file's
    assert gpano_crop({k: str(v) for k, v in sphere_fields().items()}, 1024, 321).height == 320
    assert vertical_coverage(crop) == pytest.approx((90 - 192 * 180 / 1024, 90 - 832 * 180 / 1024))
    assert gpano_crop({"ProjectionType": "equirectangular"}, 2048, 640) is None


@pytest.mark.parametrize(
    "fields, size, message",
    [
        (sphere_fields(crop=(1536, 640)), (1536, 640), "covers 270.0 of 360 degrees around (1536 of its full"),
        (sphere_fields(crop=(2100, 640)), (2100, 640), "covers 369.1 of 360 degrees around"),
        (sphere_fields(ProjectionType="cylindrical"), (2048, 640), "projection is 'cylindrical'"),
        (sphere_fields(top=500), (2048, 640), "are not within its full panorama's 1024 rows"),
        (sphere_fields(), (2048, 700), "but the image is 2048 x 700: not that shape at any scale"),
        (sphere_fields(full=(2048, 800)), (2048, 640), "not 360 x 180 degrees"),
        (sphere_fields(full=(0, 1024)), (2048, 640), "FullPanoWidthPixels is 0"),
        (sphere_fields(CroppedAreaTopPixels="top"), (2048, 640), "is not a number"),
        (sphere_fields(CroppedAreaTopPixels="inf"), (2048, 640), "is not a size in pixels: 'inf'"),
        (sphere_fields(CroppedAreaTopPixels="-3"), (2048, 640), "is not a size in pixels: '-3'"),
        ({"FullPanoWidthPixels": "2048"}, (2048, 640), "has no FullPanoHeightPixels"),
    ],
    ids=[
        "partial-circle",
        "overlapping-circle",
        "projection",
        "outside",
        "shape",
        "full-not-2-to-1",
        "zero",
        "not-a-number",
        "infinite",
        "negative",
        "missing",
    ],
)
def test_unusable_gpano_metadata_is_refused_with_its_reason(fields, size, message):
    with pytest.raises(SphereCropError, match=re.escape(message)):
        gpano_crop({k: str(v) for k, v in fields.items()}, *size)


def test_pad_to_sphere_places_the_rows_at_the_working_width():
    rng = np.random.default_rng(0)
    image = rng.integers(1, 256, (40, 128, 3), dtype=np.uint8)
    crop = SphereCrop(128, 64, 10, 128, 40, XMP_GPANO)
    full = pad_to_sphere(image, crop, 128)
    assert full.shape == (64, 128, 3) and np.array_equal(full[10:50], image)
    assert not full[:10].any() and not full[50:].any()
    assert np.array_equal(photographed_pixels(crop, 128), full.any(axis=-1))
    half = pad_to_sphere(image, crop, 64)  # the rows and the top scale with the width
    assert half.shape == (32, 64, 3) and half[5:25].all(axis=-1).all() and not half[:5].any() and not half[25:].any()
    # a file whose pixels are not quite square is resized to the rows it spans
    assert pad_to_sphere(image[:39], crop, 128)[10:50].all(axis=-1).all()


def test_the_photographed_part_of_a_levelled_photo_sphere_is_levelled_with_it():
    from ncjax.cli.outputs import photographed_part
    from ncjax.geometry.levelling import level_panorama

    crop = SphereCrop(512, 256, 48, 512, 160, XMP_GPANO)
    image = pad_to_sphere(np.full((160, 512, 3), 200, np.uint8), crop, 512)
    assert photographed_part(image, None, None) is None
    assert np.array_equal(photographed_part(image, crop, {"rotation": None}), image.any(axis=-1))
    angle = np.radians(4.0)
    rotation = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]])
    levelled = level_panorama(image, rotation)
    part = photographed_part(levelled, crop, {"rotation": rotation.tolist()})
    assert not np.array_equal(part, image.any(axis=-1))  # the band's edges moved with the image
    assert (part == (levelled.max(axis=-1) > 100)).mean() > 0.995  # all but the edges' blended pixels


@pytest.mark.parametrize("container", ["png", "jpeg"])
def test_a_photo_sphere_is_read_padded_to_its_full_panorama(tmp_path, container):
    rng = np.random.default_rng(1)
    full = cv2.resize(rng.integers(0, 256, (32, 64, 3), dtype=np.uint8), (512, 256), interpolation=cv2.INTER_CUBIC)
    rows = full[48:208]  # elevations +56.25 to -56.25 degrees
    xmp = gpano_xmp(sphere_fields((512, 256), (512, 160), top=48))
    path = tmp_path / f"sphere.{container}"
    path.write_bytes((png_with_xmp if container == "png" else jpeg_with_xmp)(rows, xmp))
    message = "512 x 160 pixels cover elevations \\+56 to -56 degrees of a 512 x 256 panorama \\(XMP GPano\\)"
    with pytest.warns(PanoramaPaddedWarning, match=message):
        image, file_size, crop = read_panorama_file(path)
    assert image.shape == (256, 512, 3) and file_size == (512, 256) and crop.top == 48
    assert not image[:48].any() and not image[208:].any()
    tolerance = 0 if container == "png" else 4  # JPEG's loss
    assert np.abs(image[48:208].astype(int) - rows.astype(int)).mean() <= tolerance


def test_a_panorama_wider_than_2_to_1_is_padded_about_the_horizon_only_when_asked(tmp_path):
    rows = np.full((200, 512, 3), 90, np.uint8)
    path = tmp_path / "band.png"
    assert cv2.imwrite(str(path), rows)
    with pytest.raises(PanoramaError, match="512 x 200 pixels is not a full 360 x 180 .*\\(ncjax reconstruct --pad-to"):
        read_panorama(path)
    with pytest.warns(PanoramaPaddedWarning, match="\\(--pad-to-sphere\\)"):
        image = read_panorama(path, assume_horizon_centred=True)
    assert image.shape == (256, 512, 3)
    assert not image[:28].any() and (image[28:228] == 90).all() and not image[228:].any()
    # taller than 2:1 is no partial sphere: still refused
    tall = tmp_path / "tall.png"
    assert cv2.imwrite(str(tall), np.zeros((300, 512, 3), np.uint8))
    with pytest.raises(PanoramaError, match="not a full 360 x 180 degree panorama \\(width must be 2 x height"):
        read_panorama(tall, assume_horizon_centred=True)


def test_a_photo_sphere_that_misses_part_of_the_circle_is_refused(tmp_path):
    path = tmp_path / "partial.png"
    path.write_bytes(png_with_xmp(np.zeros((160, 384, 3), np.uint8), gpano_xmp(sphere_fields((512, 256), (384, 160)))))
    with pytest.raises(PanoramaError, match="partial.png: it covers 270.0 of 360 degrees around"):
        read_panorama(path)


def test_a_wide_photo_sphere_is_padded_at_the_working_width(tmp_path):
    rows = np.full((1000, 4096, 3), 200, np.uint8)
    path = tmp_path / "big.png"
    path.write_bytes(png_with_xmp(rows, gpano_xmp(sphere_fields((4096, 2048), (4096, 1000), top=500))))
    with pytest.warns(PanoramaPaddedWarning, match="reconstructed at 2048 x 1024"):
        image, file_size, crop = read_panorama_file(path)
    assert image.shape == (1024, 2048, 3) and file_size == (4096, 2048)
    assert not image[:250].any() and (image[250:750] == 200).all() and not image[750:].any()


def test_only_a_file_wider_than_2_to_1_is_a_photo_sphere(tmp_path):
    stale = gpano_xmp(sphere_fields((512, 256), (512, 160), top=48))  # metadata of a crop the file no longer is
    full = tmp_path / "expanded.png"
    full.write_bytes(png_with_xmp(np.full((256, 512, 3), 7, np.uint8), stale))
    image, file_size, crop = read_panorama_file(full)
    assert crop is None and file_size == (512, 256) and (image == 7).all()
    taller = tmp_path / "taller.png"  # a few rows more than its full panorama: refused as not 2:1, not padded
    taller.write_bytes(png_with_xmp(np.zeros((270, 512, 3), np.uint8), stale))
    with pytest.raises(PanoramaError, match="512 x 270 pixels is not a full 360 x 180 degree panorama"):
        read_panorama(taller)
    near = tmp_path / "near.png"  # within the stitchers' tolerance of 2:1: resized as before, also when asked to pad
    assert cv2.imwrite(str(near), np.zeros((256, 514, 3), np.uint8))
    with pytest.warns(PanoramaResizeWarning, match="514 x 256 pixels is not exactly 2:1; resized to 514 x 257"):
        image, file_size, crop = read_panorama_file(near, assume_horizon_centred=True)
    assert crop is None and image.shape == (257, 514, 3)
    tiny = tmp_path / "tiny.png"  # padded, still too small for a panorama
    assert cv2.imwrite(str(tiny), np.zeros((10, 60, 3), np.uint8))
    with pytest.raises(PanoramaError, match="padded to the full sphere, 60 x 30 pixels is not a full 360 x 180"):
        read_panorama(tiny, assume_horizon_centred=True)
