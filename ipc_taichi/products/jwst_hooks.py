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

from .hooks import configured_subclass, spec_parameters
from .jwst_step import IPCTaichiStep

__all__ = ["configured_step", "hook_parameters"]


def hook_parameters():
    """The parameter names :class:`IPCTaichiStep` takes (those of its spec)."""
    return spec_parameters(IPCTaichiStep)


def configured_step(name, **parameters):
    """A subclass of :class:`IPCTaichiStep` named ``name`` whose parameters
    default to ``parameters`` (those given to an instance still win), defined in
    the calling module so that ``"module.name"`` imports it: a post-hook string
    with no dot in its arguments. Unknown parameter names are refused."""
    return configured_subclass(IPCTaichiStep, name, parameters)
