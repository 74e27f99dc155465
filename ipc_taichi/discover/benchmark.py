"""Time and memory of a search on sub-pixel scenes (``OVERSAMP``).

The target (docs/discover.md): a file of 3 pairs of 160x160 pixels at
``N = 5`` (800x800 SCENEs) searched in under 60 s on 2 cores. Checked by
running :func:`benchmark_oversampled`, not by a timed unit test.
"""

import os
import resource
import tempfile
import time

from .labdata import simulate_lab
from .search import discover

__all__ = ["benchmark_oversampled"]


def benchmark_oversampled(shape=(160, 160), pairs=3, oversample=5, sigma_px=0.2, seed=1):
    """Write a ``simulate-lab`` file with a hidden diffusion of ``sigma_px`` at
    ``OVERSAMP = oversample`` and search it.

    Returns
    -------
    dict
        ``wall_s`` and ``cpu_s`` of the search (the file written beforehand),
        ``peak_rss_mb`` of the process so far, the ``named`` effects, whether
        the verdict is ``complete`` and the fitted ``sigma_px``.
    """
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.fits")
        simulate_lab(path, {"charge_diffusion": sigma_px}, seed=seed, pairs=pairs, shape=shape,
                     oversample=oversample)
        wall, cpu = time.perf_counter(), time.process_time()
        report = discover(path).report
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    effects = report["final_model"]["effects"]
    return {"wall_s": wall, "cpu_s": cpu,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "named": report["missing_effects"], "complete": report["complete"],
            "sigma_px": effects.get("charge_diffusion", {}).get("sigma_px")}
