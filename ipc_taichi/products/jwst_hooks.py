"""Our JWST Step after ``refpix`` in the stock ``calwebb_detector1``: a post-hook.

The instrument teams place IPC after ``superbias`` and ``refpix``
(spacetelescope/jwst #3859); the stock pipeline runs ``ipc`` before them. Any
stpipe Step can run as a ``post_hooks`` entry of any pipeline step, so
:class:`~ipc_taichi.products.jwst_step.IPCTaichiStep` runs after ``refpix`` with the
stock ``ipc`` step skipped, no superbias file (the groups are bias-free there)
and no custom pipeline. From Python a configured instance is the hook::

    Detector1Pipeline.call("jw_uncal.fits", steps={
        "ipc": {"skip": True},
        "refpix": {"post_hooks": [IPCTaichiStep(model="nrca1_ipc.json", gain=2.05)]}})

On the command line (and in a parameter file) a hook is a string, and stpipe 1.1
reads ``"pkg.Class(kw=value)"`` by splitting the *whole* string at its last dot:
any dot in the arguments (``gain=2.05``, ``model='nrca1_ipc.json'``) makes the
hook a shell command that fails. :func:`configured_step` makes a subclass with
the parameters built in, which the string names with no arguments::

    # nrca1_ipc.py, beside the parameter file (or on $PYTHONPATH)
    from ipc_taichi.products.jwst_hooks import configured_step
    NRCA1 = configured_step("NRCA1", model="/cal/nrca1_ipc.json", gain=2.05)

    strun calwebb_detector1 jw_uncal.fits --steps.ipc.skip=true \\
        --steps.refpix.post_hooks=nrca1_ipc.NRCA1

docs/products.md has the recipe and the parameter file.
"""

import sys

from .jwst_step import IPCTaichiStep

__all__ = ["configured_step", "hook_parameters"]


def hook_parameters():
    """The parameter names :class:`IPCTaichiStep` takes (those of its spec)."""
    names = []
    for line in IPCTaichiStep.spec.splitlines():
        name = line.split("=", 1)[0].strip()
        if name and not name.startswith("#"):
            names.append(name)
    return names


def configured_step(name, **parameters):
    """A subclass of :class:`IPCTaichiStep` named ``name`` whose parameters
    default to ``parameters`` (those given to an instance still win), defined in
    the calling module so that ``"module.name"`` imports it: a post-hook string
    with no dot in its arguments. Unknown parameter names are refused."""
    known = set(hook_parameters())
    unknown = sorted(set(parameters) - known)
    if unknown:
        raise ValueError(f"configured_step {name}: unknown parameter(s) {', '.join(unknown)}; "
                         f"IPCTaichiStep takes {', '.join(sorted(known))}")
    defaults = dict(parameters)

    def __init__(self, *args, **kwargs):
        IPCTaichiStep.__init__(self, *args, **dict(defaults, **kwargs))

    module = sys._getframe(1).f_globals.get("__name__", __name__)
    return type(name, (IPCTaichiStep,), {"__init__": __init__, "__module__": module,
                                         "__qualname__": name,
                                         "__doc__": f"IPCTaichiStep with {defaults}"})
