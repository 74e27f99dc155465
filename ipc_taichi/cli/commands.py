"""The subcommands of ``ipc-taichi``: the module of :mod:`ipc_taichi.cli` that
builds each one's options, and its one-line help.

``ipc-taichi --help`` lists the commands from this table alone, without
importing their modules (nor the libraries those import); the options of a
command are built only when it is run or asked for its own ``--help``
(:func:`ipc_taichi.cli.build_parser`).
"""

__all__ = ["COMMANDS", "one_line"]

#: command -> (module of this package that builds its options, one-line help), in the
#: order ``ipc-taichi --help`` lists them
COMMANDS = {
    "couple": ("frames", "apply IPC to a signal product (forward model): IN -> OUT"),
    "decouple": ("frames", "remove IPC from a measured product (iterative Jacobi inversion): "
                           "IN -> OUT"),
    "demo": ("demo", "run the main job: the paper's worked example and a random frame "
                     "through couple -> decouple"),
    "bench": ("bench", "time decoupling: NumPy vs Taichi CPU f64/f32 (and CUDA when present)"),
    "discover": ("discover", "find which detector effect the model misses: DATA.fits -> "
                             "report"),
    "simulate-lab": ("discover", "write a lab file (SCENE/MEASURED pairs) with hidden effects"),
    "ramp-file": ("discover", "a JWST ramp (_uncal-like) as a discover ramp file: IN -> OUT.fits"),
    "calibrate": ("calibrate", "measure this detector's coupling: darks/flats/reference -> "
                               "MODEL.json"),
    "export-reference": ("export", "write a coupling model as a pipeline's IPC reference "
                                   "file (JWST ipc, Roman IPC, IPC4D): MODEL -> FILE"),
}


def one_line(command):
    """The one-line help of ``command``."""
    return COMMANDS[command][1]
