"""The ``ipc-taichi`` command line.

Every subcommand is a module of this package (plain imports: the command tree
is what this file imports); the options they share are defined once in
:mod:`ipc_taichi.cli.options`. The work is done by the library (the product
pipeline :mod:`ipc_taichi.products`, :mod:`ipc_taichi.demo`,
:mod:`ipc_taichi.bench`, :mod:`ipc_taichi.discover`); no library module
imports this package. This module dispatches and turns errors into one-line
messages and exit codes:

- 0: done;
- 1: the computation failed (e.g. divergence), or some inputs failed;
- 2: bad input or usage (file, HDU, units, law, argument);
- 3: written, but the stopping rule was not met (the output says ``IPCCONV = F``);
- 130 / 143: interrupted by SIGINT / SIGTERM (temporary files removed, nothing
  written at the output path).
"""

import argparse
import logging
import signal
import sys
import warnings

from .. import __version__
from ..errors import ConvergenceWarning, DivergenceError
from ..interrupts import clear_stop, request_stop
from ..products.conventions import ProductWarning
from . import bench, calibrate, demo, discover, frames

__all__ = ["main", "build_parser", "Terminated"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNCONVERGED = 0, 1, 2, 3


class Terminated(KeyboardInterrupt):
    """SIGTERM (what batch schedulers send) raised as an exception, so that
    every ``with`` block on the way out removes its temporary files."""


def build_parser():
    """The ``ipc-taichi`` parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="ipc-taichi",
        description="Simulate and remove signal-dependent interpixel capacitance (IPC) in "
                    "hybrid IR detector products (Donlon, Ninkov & Baum, JATIS 2018), with "
                    "Taichi kernels on the CPU or a CUDA GPU.",
        epilog="Run 'ipc-taichi COMMAND --help' for each command. Pixel convention: "
               "image[y, x]; FITS NAXIS1 = x. Exit codes: 0 done, 1 failed, 2 bad input, "
               "3 written but not converged, 130/143 interrupted.")
    parser.add_argument("--version", action="version", version=f"ipc_taichi {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    frames.add_parsers(sub)
    demo.add_parser(sub)
    bench.add_parser(sub)
    discover.add_parsers(sub)
    calibrate.add_parser(sub)
    return parser


def _terminate(signum, frame):
    exc = Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
    request_stop(exc)  # in case a library swallows it (see ipc_taichi.interrupts)
    raise exc


def _show_warning(message, category, filename, lineno, file=None, line=None):
    kind = "warning" if issubclass(category, (ConvergenceWarning, ProductWarning)) else \
        category.__name__
    print(f"ipc-taichi: {kind}: {message}", file=sys.stderr)


def main(argv=None):
    """Run ``ipc-taichi`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    args = build_parser().parse_args(argv)
    quiet = getattr(args, "quiet", False)
    # the runtime's CUDA notice is a logged warning; --quiet keeps only errors
    logging.basicConfig(format="ipc-taichi: %(message)s",
                        level=logging.ERROR if quiet else logging.WARNING)
    from astropy.utils.exceptions import AstropyWarning

    clear_stop()
    previous = {sig: signal.signal(sig, _terminate) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        with warnings.catch_warnings():  # restored on return (main may run in-process)
            warnings.showwarning = _show_warning
            warnings.filterwarnings("once", category=AstropyWarning)  # a bad card: once
            for category in (ConvergenceWarning, ProductWarning):  # said to the user, always
                warnings.filterwarnings("always", category=category)
            return int(args.run(args) or 0)
    except DivergenceError as exc:
        print(f"ipc-taichi: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"ipc-taichi: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Terminated:
        print("ipc-taichi: terminated (SIGTERM); unfinished outputs removed", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print("ipc-taichi: interrupted; unfinished outputs removed", file=sys.stderr)
        return 128 + signal.SIGINT
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        clear_stop()


if __name__ == "__main__":
    sys.exit(main())
