"""Two assumptions of the calibration tested on the data, not stated (issue 35, item 5).

1. **Read noise uncorrelated between neighbours.** A read-noise correlation
   ``rho(l)`` between pixels at lag ``l`` adds ``rho sigma_read^2`` to a flat's
   covariance at that lag, which reads as coupling: ``w alpha`` moves by
   ``rho sigma_read^2 / (2 V)`` at a flat of shot variance ``V`` (a 1 %
   correlation moves the measured IPC by ~5 % at low levels). It is measured
   per lag on the darks' group differences (:func:`.maps.read_noise_covariance`),
   taken out of the flats' covariances of the map (:mod:`.maps`), and its
   effect on the law's flat points is stated.
2. **Hot pixels see no brighter-fatter.** A hot pixel's charge is made in its
   own diode, not steered by the field as photo-charge is; if it were, the
   charge collected would be deflected to the neighbours in proportion to the
   charge already there, and ``alpha(S, 0)`` would rise with ``S`` by ``a_nn S
   / 2`` (``a_nn`` the flats' nearest brighter-fatter coefficient per
   electron, averaged over the integration). The hot pixels' measured slope is
   compared with 0 and with that prediction; the report says which holds.
"""

import numpy as np

__all__ = ["SIGMA", "read_noise_correlation", "hot_pixel_brighter_fatter"]

SIGMA = 2.0
"""Standard errors that tell a slope from 0 or from the prediction."""


def read_noise_correlation(read_cov, flat_levels, alpha):
    """The darks' read-noise correlation per lag and what it does to the flats.

    Parameters
    ----------
    read_cov : dict or None
        :func:`.maps.read_noise_covariance` of the darks.
    flat_levels : sequence of float
        Mean charge [e-] of the flat points.
    alpha : float
        The law's nearest-neighbour coupling (to state the effect relative to it).
    """
    if read_cov is None:
        return {"assumption": "read noise uncorrelated between neighbours", "tested": False,
                "note": "read noise between neighbours: not tested (no dark ramp with 3 or "
                        "more reads of the flats' shape)"}
    cov = read_cov["cov"]
    var = cov[(0, 0)][0]
    corr = {f"{dy},{dx}": {"value": c[0] / var, "error": c[1] / var}
            for (dy, dx), c in cov.items() if (dy, dx) != (0, 0)}
    worst = max(corr.values(), key=lambda c: abs(c["value"]))
    significant = any(abs(c["value"]) > SIGMA * c["error"] for c in corr.values())
    effect = None
    if flat_levels and alpha:
        # per read, the covariance is half that of a difference of two reads
        level = float(np.min(flat_levels))
        effect = abs(worst["value"]) * var / 2.0 / (2.0 * level) / alpha
    parts = ", ".join(f"lag {k}: {100 * c['value']:+.3f} +- {100 * c['error']:.3f} %"
                      for k, c in corr.items())
    note = (f"read noise between neighbours: correlation {parts} "
            f"({'significant' if significant else 'consistent with 0'}); taken out of the "
            "map's flat covariances")
    if effect is not None:
        note += (f"; left in the law's flat points, where it moves alpha(S,S) by at most "
                 f"{100 * effect:.2g} % (at {min(flat_levels):.4g} e-)")
    return {"assumption": "read noise uncorrelated between neighbours", "tested": True,
            "correlation": corr, "significant": bool(significant),
            "effect_on_flat_alpha": effect, "holds": not significant, "note": note}


def hot_pixel_brighter_fatter(hot_slope, bf):
    """The hot pixels' alpha(S, 0) slope against the brighter-fatter prediction.

    Parameters
    ----------
    hot_slope : dict or None
        ``{"slope_per_10ke", "error"}`` of the hot pixels' nearest-neighbour
        alpha(S, 0) (mean of x and y).
    bf : dict
        The report's ``brighter_fatter`` (``kernel``, ``kernel_error`` 5x5 per
        electron, ``[2+dy][2+dx]``).
    """
    out = {"assumption": "hot pixels see no brighter-fatter", "tested": False}
    if hot_slope is None or not bf.get("measured") or bf.get("kernel") is None:
        why = ("fewer than 2 hot-pixel bins" if hot_slope is None else
               "no brighter-fatter kernel (give flat ramps)")
        return {**out, "note": f"hot pixels and brighter-fatter: not tested ({why})"}
    k = np.asarray(bf["kernel"], float)
    e = np.asarray(bf.get("kernel_error") or np.zeros((5, 5)), float)
    nn = [(2, 1), (2, 3), (1, 2), (3, 2)]
    a_nn = float(np.mean([k[i] for i in nn]))
    a_err = float(np.sqrt(np.sum([e[i] ** 2 for i in nn])) / 4)
    predicted = a_nn * 1e4 / 2.0
    pred_err = a_err * 1e4 / 2.0
    s, err = hot_slope["slope_per_10ke"], hot_slope["error"]
    from_zero = abs(s) / err if err > 0 else np.inf
    from_bf = abs(s - predicted) / np.hypot(err, pred_err) if err > 0 else np.inf
    if from_zero <= SIGMA < from_bf:
        verdict, holds = "holds: the hot pixels' slope is consistent with 0, not with it", True
    elif from_bf <= SIGMA < from_zero:
        verdict, holds = ("fails: the hot pixels rise as brighter-fatter predicts (their "
                          "law at (S, 0) holds brighter-fatter)"), False
    elif from_bf > SIGMA and from_zero > SIGMA:
        verdict, holds = ("neither: the hot pixels' slope is neither 0 nor brighter-fatter's "
                          "(non-linear IPC, or another effect)"), None
    else:
        verdict, holds = "cannot tell: the prediction is within the slope's error", None
    note = (f"hot pixels and brighter-fatter: alpha(S,0) slope {100 * s:+.4f} +- "
            f"{100 * err:.4f} % per 10 ke-, brighter-fatter would give {100 * predicted:+.4f} "
            f"+- {100 * pred_err:.4f} %: the assumption {verdict}")
    return {**out, "tested": True, "hot_slope_per_10ke": s, "error": err,
            "predicted_per_10ke": predicted, "predicted_error": pred_err, "holds": holds,
            "note": note}
