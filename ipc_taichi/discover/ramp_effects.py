"""The effects only ramps show: their records, physical forms, limits and
contradictions (``docs/discovery_format.md``, "Ramps"; the frame vocabulary
is :mod:`.effects`).

``persistence``
    ``fraction``, ``tau_s``: charge trapped during earlier light is released
    during this integration at the rate ``fraction E exp(-t / tau) / tau``
    (e-/s), ``E`` the earlier charge of the pixel and ``t`` the time after
    reset: by read ``i`` it has added ``fraction E (1 - exp(-t_i / tau))``
    collected electrons (coupled and shot-noisy like any charge). ``E`` is
    the previous ramp pair's SCENE times its last read's time (the earlier
    exposure of these pixels); for the first pair of a file, its own (the
    same light before this integration, as in a series of lab flats).
    Contradicted by ``fraction <= 0`` (a deficit where light was is not an
    after-image); outside the physical range above ``fraction`` 5 % (HgCdTe
    releases a few tenths of a per cent up to a few per cent of the earlier
    charge) or with ``tau`` above 20 times the integration (a constant rate:
    dark current, not a decay).
``correlated_read_noise``
    ``row_variance_e2``, ``column_variance_e2``: at each read an offset
    shared by every pixel of a row (a column), Gaussian of this variance
    (e-^2): the 1/f noise of a readout channel. Contradicted when neither is
    positive, or when the lines with no light on or next to them (by SCENE)
    show under half of it (a misfit of the signal at the sources, e.g. brighter-fatter,
    raises the lines through them only); outside the physical range when the
    shared RMS exceeds 3 times ``READNOIS`` (a read noise is not several
    times what the detector's own characterisation says, as for
    ``excess_read_noise``).
``random_telegraph_noise``
    ``fraction``, ``jump_e``: that share of the pixels switches between two
    levels ``jump_e`` apart from read to read; such pixels are given their own
    levels (left out of the gap). Contradicted when the pixels off the model
    do not come back (their large increments all of one sign: a step such as
    a cosmic ray, or a signal the model lacks); outside the physical range
    above 5 % of the pixels (then it is not a few defective pixels).
"""

import math

import numpy as np

from .effects import Effect, Param

__all__ = ["RAMP_EFFECTS", "released", "ramp_contradiction", "ramp_implausible",
           "RAMP_LIMITS"]

RAMP_EFFECTS = {e.name: e for e in (
    Effect("persistence", "collection",
           (Param("fraction", 0.0, -0.05, 0.2, 0.002), Param("tau_s", 10.0, 0.01, 1e5, 1.0)),
           "a signal left by an earlier exposure that decays during this one"),
    Effect("correlated_read_noise", "variance",
           (Param("row_variance_e2", 0.0, -1e4, 1e5, 1.0),
            Param("column_variance_e2", 0.0, -1e4, 1e5, 1.0)),
           "read noise shared between the pixels of a row or a column"),
    Effect("random_telegraph_noise", "pixels",
           (Param("fraction", 0.0, 0.0, 1.0, 1e-3), Param("jump_e", 0.0, -1e5, 1e5, 1.0)),
           "pixels whose signal jumps between two levels from read to read"),
)}

# persistence: at most this fraction of the earlier charge, a decay at most this
# many integrations long; shared read noise at most this many READNOIS; telegraph
# pixels at most this share of the pixels
DARK_SHARE = 0.5  # shared read noise: the dark lines must show this share of it
RAMP_LIMITS = {"persistence": 0.05, "persistence_tau": 20.0, "correlated_read_noise": 3.0,
               "random_telegraph_noise": 0.05}


def earlier_charge(ramps, k):
    """``E`` of ramp ``k`` (module docstring), electrons per pixel."""
    source = ramps[k - 1] if k > 0 else ramps[k]
    rate = source.rate
    n = source.oversample
    if n > 1:
        rate = rate.reshape(rate.shape[0] // n, n, rate.shape[1] // n, n).sum(axis=(1, 3))
    return np.nan_to_num(rate) * float(source.times[-1])


def released(params, ramps, k):
    """The persistence charge collected by each read of ramp ``k``,
    ``fraction E (1 - exp(-t_i / tau))``, ``(NREADS, ny, nx)``."""
    t = ramps[k].times
    growth = 1.0 - np.exp(-t / max(float(params["tau_s"]), 1e-6))
    return float(params["fraction"]) * earlier_charge(ramps, k)[None] * growth[:, None, None]


def ramp_contradiction(name, params, extra=None):
    """Why ``params`` contradict ramp effect ``name``, or ``None``. ``extra``:
    for telegraph noise the share of its pixels whose increments go both
    ways, for shared read noise the share of it the dark lines show (a read
    noise is the same where no light falls)."""
    if name == "persistence" and params["fraction"] <= 0:
        return (f"a deficit where earlier light was (fraction {params['fraction']:.4g} <= 0) "
                "is not an after-image")
    if name == "correlated_read_noise" and max(params["row_variance_e2"],
                                               params["column_variance_e2"]) <= 0:
        return "rows and columns share less noise than independent pixels would"
    if name == "correlated_read_noise" and extra is not None and extra < DARK_SHARE:
        return (f"the lines share it where light falls, not where none does (the lines with "
                f"no light on or next to them show {100 * extra:.0f} % of it): a misfit of the "
                "signal, not read noise")
    if name == "random_telegraph_noise" and extra is not None and extra <= 0.5:
        return (f"only {100 * extra:.0f} % of the pixels off the model jump both ways: "
                "steps that do not return (a cosmic ray, or a signal the model lacks)")
    return None


def ramp_implausible(name, params, readnoise, duration):
    """Why ``params`` lie outside the physical range of ramp effect ``name``
    (:data:`RAMP_LIMITS`; ``duration`` the integration, s), or ``None``."""
    if name == "persistence":
        if params["fraction"] > RAMP_LIMITS["persistence"]:
            return (f"{100 * params['fraction']:.1f} % of the earlier charge released (at "
                    f"most {100 * RAMP_LIMITS['persistence']:g} % is plausible)")
        if params["tau_s"] > RAMP_LIMITS["persistence_tau"] * duration:
            return (f"a decay time of {params['tau_s']:.3g} s, {params['tau_s'] / duration:.0f} "
                    "integrations: a constant rate (dark current), not a decay")
    if name == "correlated_read_noise":
        shared = math.sqrt(max(params["row_variance_e2"], 0.0)
                           + max(params["column_variance_e2"], 0.0))
        if readnoise and shared > RAMP_LIMITS["correlated_read_noise"] * readnoise:
            return (f"{shared:.1f} e- shared by rows and columns, "
                    f"{shared / readnoise:.1f} times READNOIS")
    if name == "random_telegraph_noise" and \
            params["fraction"] > RAMP_LIMITS["random_telegraph_noise"]:
        return (f"{100 * params['fraction']:.1f} % of the pixels (at most "
                f"{100 * RAMP_LIMITS['random_telegraph_noise']:g} % are a few defective pixels)")
    return None
