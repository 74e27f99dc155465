"""Write one noise-free grid point of the binary study as FITS, for independent checks.

Writes ``OUT_truth.fits`` (the scene, exactly as the grid makes it, with the
star positions and fluxes in the header) and ``OUT_epsf_<stage>.fits`` (the
4x effective PSFs the grid fits with: truth, and coupled/decoupled at the
primary's flux). Couple and decouple the truth frame with the command line
(``ipc-taichi couple``, ``ipc-taichi decouple``) and fit with photutils: see
docs/photometry.md. Example::

    python scripts/binary_frame.py --brightness bright --ratio 0.25 --separation 3 \\
        --dx 0.25 --dy 0.5 /tmp/pair
"""

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))

from analysis.binary import FLUX, BinaryGrid, pair_frames  # noqa: E402
from analysis.psf import effective_psf, optical_psf  # noqa: E402
from ipc_taichi.fitsio import write_image  # noqa: E402


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="output prefix (OUT_truth.fits, OUT_epsf_*.fits)")
    parser.add_argument("--brightness", choices=sorted(FLUX), default="bright")
    parser.add_argument("--ratio", type=float, default=0.25, help="secondary / primary flux")
    parser.add_argument("--separation", type=float, default=3.0, help="pixels, along x")
    parser.add_argument("--dx", type=float, default=0.0, help="primary sub-pixel offset in x")
    parser.add_argument("--dy", type=float, default=0.0, help="primary sub-pixel offset in y")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)

    grid = BinaryGrid()
    psf = optical_psf(grid.psf_source, grid.oversample)
    pos, (flux1, flux2), frames = pair_frames(psf, args.brightness, args.ratio, args.separation,
                                              [(args.dx, args.dy)], grid.law, grid.half,
                                              oversample=grid.oversample)
    (x1, y1), (x2, y2) = pos[0]
    keywords = {"BINX1": (x1, "primary x [px, 0-based, pixel centres]"),
                "BINY1": (y1, "primary y"), "BINF1": (flux1, "primary flux [e-]"),
                "BINX2": (x2, "secondary x"), "BINY2": (y2, "secondary y"),
                "BINF2": (flux2, "secondary flux [e-]")}
    write_image(f"{args.out}_truth.fits", frames["truth"][0], overwrite=args.overwrite,
                keywords=keywords, history=["ipc_taichi binary study: noise-free truth frame"])
    for stage in ("truth", "coupled", "decoupled"):
        epsf = effective_psf(psf, flux1, stage=stage, law=grid.law, oversample=grid.oversample)
        write_image(f"{args.out}_epsf_{stage}.fits", epsf, overwrite=args.overwrite,
                    keywords={"OVERSAMP": (grid.oversample, "samples per detector pixel"),
                              "EPSFSTAG": (stage, "truth / coupled / decoupled"),
                              "EPSFFLUX": (flux1, "source flux the IPC saw [e-]")})
    print(f"{args.out}_truth.fits: primary ({x1:g}, {y1:g}) {flux1:.6g} e-, "
          f"secondary ({x2:g}, {y2:g}) {flux2:.6g} e-")


if __name__ == "__main__":
    main()
