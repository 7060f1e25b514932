"""What the ``ncjax`` commands' parsers share: the ``--help`` formatter and the ``--size HxW`` and
``--texture-size`` options."""

from __future__ import annotations

import argparse
import re


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """``--help`` that ends each option's text with its default, ``(default: X)``.

    Left as they are: texts that already name their default, options without a default
    (None: their text says what their absence means), flags (no value) and positionals.
    """

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (
            "default" in text
            or not action.option_strings
            or action.nargs == 0
            or action.required
            or action.default in (None, argparse.SUPPRESS)
        ):
            return text
        return f"{text} (default: %(default)s)" if text else "(default: %(default)s)"


def parse_size(text: str) -> tuple[int, int]:
    """``--size HxW``: the image height and width, even and at least 4 x 8 (a ValueError says why not)."""
    match = re.fullmatch(r"(\d+)x(\d+)", text)
    if not match:
        raise ValueError(f"--size must be HxW, e.g. 512x1024, got {text!r}")
    height, width = int(match.group(1)), int(match.group(2))
    if height < 4 or width < 8 or width % 2 or height % 2:
        raise ValueError(f"--size must be even sizes of at least 4x8 (HxW), got {text!r}")
    return height, width


def parse_texture_size(text: str) -> int:
    """``--texture-size``: texels on a side of the textured room's texture, at least MIN_TEXTURE_SIZE."""
    from ..viz.room_texture import MIN_TEXTURE_SIZE

    try:
        size = int(text)
    except ValueError:
        size = 0
    if size < MIN_TEXTURE_SIZE:
        raise argparse.ArgumentTypeError(
            f"the texture size must be a whole number of texels >= {MIN_TEXTURE_SIZE}, got {text!r}"
        )
    return size


def add_texture_argument(parser: argparse.ArgumentParser) -> None:
    """``--texture-size``: the side of the square texture of ``<name>.glb`` and ``<name>.html``."""
    parser.add_argument(
        "--texture-size",
        type=parse_texture_size,
        metavar="TEXELS",
        help="side of the square texture that carries the panorama onto the room's walls, floor and ceiling "
        "in <name>.glb and <name>.html (default: the panorama's width)",
    )
