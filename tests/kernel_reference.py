"""Record couple/decouple outputs of the Taichi kernels (CPU arch) for
tests/test_kernel_identity.py: the kernel code may be restructured, but these
bytes must not change.

Run from the repository root::

    IPC_TAICHI_ARCH=cpu python -m tests.kernel_reference

Writes ``tests/data/kernel_reference.json``: the SHA-256 of each output's
bytes (the arrays themselves would take a megabyte). Recorded from the
kernels of commit 57167aa (before the two layouts were built from shared
device functions); data: seeded synthetic frames made here (no external data,
same licence as the repository).

The ``f32`` entries first recorded were f64 outputs: ``init("cpu", "f32")``
did not stick and ``couple``/``decouple`` without ``precision=`` went back to
f64 (issue 28). They, and the four ``f64/*/table_nearest/*/decouple``
entries (which 57167aa's own kernels no longer reproduce on this machine;
the cause was not traced, every other entry they reproduce), were recorded
again from commit 57167aa's kernels with the precision passed explicitly; the
current kernels give all 144 bit for bit.

The eight ``*/constant_nearest/nomask/couple`` and ``/decouple`` entries were
recorded again when the constant law without ``ok`` gating took pre-combined
coefficients (``StepPlan.combined``, issue 28): an intended change of rounding,
at most 7.3e-12 e- (4e-15 relative) in f64 and 0.0039 e- (one float32 unit at
6e4 e-) in f32 from the old outputs, the same iterations and stopping-rule
maxima; every other entry unchanged.
"""

import hashlib
import json
import os
import sys

import numpy as np

import ipc_taichi
from ipc_taichi import Geometry, TabulatedLaw, donlon2018

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")


def cases():
    """``(name, kwargs)`` of every recorded case (model arguments of couple/decouple)."""
    aniso = Geometry.terms(horizontal=1.0, vertical=0.8, diagonal=0.3, second=0.1)
    table = TabulatedLaw.from_callable(donlon2018().alpha, (0.0, 70000.0), n=33, name="t")
    return [
        ("nearest_zero", dict(law="donlon2018")),
        ("aniso_isolated", dict(law="donlon2018", geometry=aniso, edge="isolated")),
        ("aniso_zero", dict(law="donlon2018", geometry=aniso)),
        ("constant_nearest", dict(law="constant:0.0125")),
        ("constant_aniso_isolated", dict(law="constant:0.0125", geometry=aniso,
                                         edge="isolated")),
        ("table_nearest", dict(law=table)),
    ]


def frames():
    """A 2-frame stack (29 x 23) with a NaN pixel in frame 1, and a mask."""
    rng = np.random.default_rng(2018)
    truth = rng.uniform(0, 60000, (2, 29, 23))
    truth[1, 7, 5] = np.nan
    mask = np.zeros((29, 23), bool)
    mask[13, 17] = True
    return truth, mask


def record():
    truth, mask = frames()
    out = {}
    for precision in ("f64", "f32"):
        ipc_taichi.init("cpu", precision)
        for layout in ("sweep", "pixel", "lanes"):
            for name, kw in cases():
                for masked in (False, True):
                    m = mask if masked else None
                    key = f"{precision}/{layout}/{name}/{'mask' if masked else 'nomask'}"
                    run = dict(layout=layout, mask=m, precision=precision, **kw)
                    measured = ipc_taichi.couple(truth, **run)
                    signal, infos = ipc_taichi.decouple(measured, full_output=True, **run)
                    out[key + "/couple"] = digest(measured)
                    out[key + "/decouple"] = digest(signal)
                    out[key + "/max_delta"] = digest(sum((i.max_delta for i in infos), []))
    return out


def digest(values):
    """SHA-256 of an output's bytes (little-endian, its own dtype)."""
    arr = np.ascontiguousarray(np.asarray(values))
    return hashlib.sha256(arr.astype(arr.dtype.newbyteorder("<")).tobytes()).hexdigest()


if __name__ == "__main__":
    path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "kernel_reference.json")
    with open(path, "w") as f:
        json.dump(record(), f, indent=1, sort_keys=True)
    print(path)
