"""The ``ipc-taichi`` command line.

Every subcommand is a module of this package; the options they share are
defined once in :mod:`ipc_taichi.cli.options`, and the table of commands (each
one's module and one-line help) is :data:`ipc_taichi.cli.commands.COMMANDS`. A
command's module, and the libraries it needs, are imported only when that
command runs: ``ipc-taichi --help`` imports none of them and answers at once.
The work is done by the library (the product pipeline
:mod:`ipc_taichi.products`, :mod:`ipc_taichi.demo`, :mod:`ipc_taichi.bench`,
:mod:`ipc_taichi.discover`); no library module imports this package. This module
dispatches and turns errors into one-line messages and exit codes:

- 0: done;
- 1: the computation failed (e.g. divergence), or some inputs failed;
- 2: bad input or usage (file, HDU, units, law, argument);
- 3: written, but the stopping rule was not met (the output says ``IPCCONV = F``);
- 130 / 143: interrupted by SIGINT / SIGTERM (temporary files removed, nothing
  written at the output path), at any moment, also while the libraries load.

A run ends quickly: at exit the loaded libraries are not traversed again by
Python's garbage collector (:func:`exit_quickly`).
"""

import argparse
import atexit
import gc
import importlib
import logging
import signal
import sys
import warnings

from .. import __version__
from ..errors import ConvergenceWarning, DivergenceError
from ..interrupts import check_stop, clear_stop, request_stop, stop_requested
from .commands import COMMANDS

__all__ = ["main", "build_parser", "Terminated", "exit_quickly"]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNCONVERGED = 0, 1, 2, 3
_at_exit = []  # what main registered with atexit (once per process)


class Terminated(KeyboardInterrupt):
    """SIGTERM (what batch schedulers send) raised as an exception, so that
    every ``with`` block on the way out removes its temporary files."""


def build_parser(commands=None):
    """The ``ipc-taichi`` parser.

    Parameters
    ----------
    commands : iterable of str, optional
        The subcommands whose options are built (default: every one). The
        others are listed with their one-line help only, so that their modules
        are not imported.
    """
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
    wanted = set(COMMANDS if commands is None else commands)
    for module_name in dict.fromkeys(module for module, _ in COMMANDS.values()):
        names = [name for name, (module, _) in COMMANDS.items() if module == module_name]
        if wanted.intersection(names):
            module = importlib.import_module(f".{module_name}", __name__)
            (getattr(module, "add_parsers", None) or module.add_parser)(sub)
        else:
            for name in names:
                sub.add_parser(name, help=COMMANDS[name][1])
    return parser


def _command(argv):
    """The subcommand ``argv`` names (its first word that is not an option), as a
    tuple of none or one."""
    words = [word for word in argv if not word.startswith("-")]
    return tuple(words[:1])


def _terminate(signum, frame):
    exc = Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()
    request_stop(exc)  # in case a library swallows it (see ipc_taichi.interrupts)
    raise exc


def _show_warning(message, category, filename, lineno, file=None, line=None):
    from ..products.conventions import ProductWarning

    kind = "warning" if issubclass(category, (ConvergenceWarning, ProductWarning)) else \
        category.__name__
    print(f"ipc-taichi: {kind}: {message}", file=sys.stderr)


def _ended(exc):
    """The exit code of a run ended by ``exc``, its one line said; anything else
    (argparse's exit, a bug's traceback) raised again. A signal comes first: a
    library may turn the KeyboardInterrupt of a signal into an error of its own
    (NumPy interrupted while importing its extension raises ImportError)."""
    stop = stop_requested()
    if isinstance(exc, Exception) and stop is not None:
        exc = stop
    if isinstance(exc, Terminated):
        print("ipc-taichi: terminated (SIGTERM); unfinished outputs removed", file=sys.stderr)
        return 128 + signal.SIGTERM
    if isinstance(exc, KeyboardInterrupt):
        print("ipc-taichi: interrupted; unfinished outputs removed", file=sys.stderr)
        return 128 + signal.SIGINT
    if isinstance(exc, DivergenceError):
        print(f"ipc-taichi: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    if isinstance(exc, (ValueError, OSError, RuntimeError)):
        print(f"ipc-taichi: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    raise exc


def exit_quickly():
    """At the process's exit (after the exit handlers registered later): the
    Taichi runtime ended (:func:`ipc_taichi.runtime.finish`: Taichi writes its
    offline cache's index), then every object frozen (``gc.freeze``), so that
    the interpreter's last collections skip them; the system takes the memory
    back with the process. Registered by :func:`main`, once per process.

    Without it the exit of a small run costs 0.15-0.18 s CPU (the last
    collections over the ~90 000 objects NumPy, astropy and Taichi leave),
    and Taichi's cache depends on them: it is written when its program object
    is collected."""
    runtime = sys.modules.get("ipc_taichi.runtime")
    if runtime is not None:
        runtime.finish()
    gc.freeze()


def main(argv=None):
    """Run ``ipc-taichi`` with ``argv`` (default ``sys.argv[1:]``); return the exit code.

    SIGINT and SIGTERM are handled from the first line on: a Ctrl-C while the
    libraries are still loading ends the run with one line and code 130, as
    one during the work does.
    """
    clear_stop()
    previous = {sig: signal.signal(sig, _terminate) for sig in (signal.SIGTERM, signal.SIGINT)}
    if exit_quickly not in _at_exit:
        atexit.register(exit_quickly)
        _at_exit.append(exit_quickly)
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        args = build_parser(_command(argv)).parse_args(argv)
        quiet = getattr(args, "quiet", False)
        # the runtime's CUDA notice is a logged warning; --quiet keeps only errors
        logging.basicConfig(format="ipc-taichi: %(message)s",
                            level=logging.ERROR if quiet else logging.WARNING)
        from astropy.utils.exceptions import AstropyWarning

        from ..products.conventions import ProductWarning

        with warnings.catch_warnings():  # restored on return (main may run in-process)
            warnings.showwarning = _show_warning
            warnings.filterwarnings("once", category=AstropyWarning)  # a bad card: once
            for category in (ConvergenceWarning, ProductWarning):  # said to the user, always
                warnings.filterwarnings("always", category=category)
            code = int(args.run(args) or 0)
        check_stop()  # a signal a library swallowed still ends the run as interrupted
        return code
    except BaseException as exc:  # noqa: B036 (what is not ours to say is raised again)
        return _ended(exc)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        clear_stop()


if __name__ == "__main__":
    sys.exit(main())
