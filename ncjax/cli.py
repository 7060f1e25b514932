"""The ``ncjax`` command line."""

from __future__ import annotations

import argparse
import sys

CONVENTIONS = """\
frame      metres, right-handed, z up (revolution axis), circle of optical centres in z = 0
azimuth    varphi = pi - 2 pi (u + 0.5) / W   (decreases to the right)
elevation  phi = pi/2 - pi (v + 0.5) / H      (top row looks up)
centre     column u sees from rc (cos varphi, sin varphi, 0), rays radially outward
ray        (cos phi cos varphi, cos phi sin varphi, sin phi, rc sin phi sin varphi, -rc sin phi cos varphi, 0)
projection varphi = atan2(y, x), phi = atan2(z, sqrt(x^2 + y^2) - rc); NaN inside the circle
wall       ceiling line (ux, uy, 0, -h_c uy, h_c ux, -d), floor line the same with h_f
"""


def _info(args: argparse.Namespace) -> int:
    import jax

    import ncjax

    print(f"ncjax {ncjax.__version__}, jax {jax.__version__}, devices: {', '.join(str(d) for d in jax.devices())}")
    print(CONVENTIONS, end="")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ncjax`` console script."""
    from ncjax import __version__

    parser = argparse.ArgumentParser(prog="ncjax", description="Metric room layouts from non-central panoramas.")
    parser.add_argument("--version", action="version", version=f"ncjax {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    info = commands.add_parser("info", help="versions, devices and the camera conventions")
    info.set_defaults(run=_info)
    args = parser.parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
