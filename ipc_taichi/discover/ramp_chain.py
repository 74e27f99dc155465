"""The frame effects that ramps tell apart by their time structure:
``brighter_fatter``, ``signal_dependent_ipc``, ``classical_nonlinearity`` and
the IPC geometry terms fitted to a ramp file's increments, read by read
(``docs/discover.md``, "Ramps"; the forms are the frame vocabulary's,
:mod:`.effects`).

The physical forms, evaluated at every read ``i`` (:func:`~.ramps.expected_mean`)
---------------------------------------------------------------------------
- ``brighter_fatter`` acts while collecting: the charge of read ``i`` is
  ``SCENE t_i`` collected with boundaries moved by the charge already
  collected (:func:`~.effects.brighter_fatter`, integrated from the reset to
  ``t_i``), so the flux a pixel keeps falls progressively as it fills and
  its neighbours' increments rise by what it loses, read after read.
- ``signal_dependent_ipc`` acts at readout: the coupling of the charge present
  at read ``i`` by the donlon2018-family law of that charge
  (:meth:`~.model.DetectorModel.ipc_law`); a read depends on the charge at
  that read only, and the collected charge itself is untouched.
- ``classical_nonlinearity`` acts on each pixel's read value after the
  coupling (:func:`~.effects.nonlinearity`): its own increments shrink as its
  level grows, and nothing moves to its neighbours.
- ``diagonal_ipc``, ``anisotropic_ipc``, ``second_neighbor_ipc`` act at
  readout like the law: the frame records' weights on the nearest coupling
  applied to the charge present at read ``i`` (so offered only where the
  current law has a nearest coupling, ``alpha(0, 0) > 0``).

Fit (:func:`fit_frame_effect`)
------------------------------
The effect's strength parameters (:data:`FITTED`; the others at the frame
vocabulary's starting values) by least squares of the increments whitened
by the current model's covariance (:func:`~.ramps.increment_factors`), the
rest of the model fixed; evidence ``delta chi^2 - k ln n``. Its gates are the
frame vocabulary's (:func:`~.effects.contradiction`,
:func:`~.effects.implausible`, the signature, :func:`signature_refusal`) and,
for the two that move charge between neighbours, :func:`rival_contradiction`:
both are fitted to the same increments, and the one whose time structure
fits worse by more than the evidence threshold is not the effect; when
neither is ahead by that much the ramps do not tell them apart and neither
is named.
"""

import math

import numpy as np
from scipy.optimize import least_squares

from ..brighterfatter import kernel_from_deflection
from ..errors import GeometryError, LawError
from .effects import EFFECTS
from .fitting import FitResult
from .gates import SIGNATURE_Z2, signature
from .ramp_cross import CROSS_LAGS, CrossResponse
from .ramps import RampModel, expected_mean, expected_reads, increment_factors, whiten

__all__ = ["FITTED", "RIVALS", "offered", "fit_frame_effect", "rival_contradiction",
           "signature_refusal"]

FITTED = {"brighter_fatter": ("deflection_x_at_50ke", "deflection_y_at_50ke", "reach"),
          "signal_dependent_ipc": ("amp_diff", "amp_level", "alpha_floor"),
          "classical_nonlinearity": ("deficit_at_50ke",),
          "diagonal_ipc": ("alpha_diag",),
          "anisotropic_ipc": ("weight_horizontal", "weight_vertical"),
          "second_neighbor_ipc": ("alpha_second",)}
"""The parameters fitted on ramps, per effect (the others stay at the frame
vocabulary's starting values: brighter-fatter's boundary-shift picture, no
cubic term)."""

RIVALS = ("brighter_fatter", "signal_dependent_ipc")
_FAILED = 1e3  # whitened residual for parameters the engine rejects (a negative alpha)


def offered(model):
    """The frame effects a ramp search may add to ``model`` (a
    :class:`~.ramps.RampModel`): those not in it that their records offer on
    its current law (:meth:`~.record.Effect.offered`: ``signal_dependent_ipc``
    only on a constant law, the geometry terms only on a law with a nearest
    coupling ``alpha(0, 0) > 0``, as for frames)."""
    frame = model.frame
    law = frame.ipc_law()
    return [name for name in FITTED
            if name not in frame.effects and EFFECTS[name].offered(law)]


def _parts(model, ramps, response=False):
    """Per ramp: the Cholesky factors of the increments under ``model``, the
    measured increments of the valid pixels and the valid mask; with
    ``response`` the brighter-fatter response of the cross-read products
    (:class:`~.ramp_cross.CrossResponse`), else ``None``."""
    parts, out = [], CrossResponse() if response else None
    for k, ramp in enumerate(ramps):
        mean, shot, r = expected_reads(model, ramp, model.afterglow(ramps, k))
        valid = model.valid(ramp)
        chol, _, _ = increment_factors(ramp.reads, mean, shot, r, valid, ramp)
        parts.append((chol, np.diff(ramp.reads, axis=0, prepend=0.0)[:, valid], valid))
        if response:
            out.add(chol, np.diff(mean, axis=0, prepend=0.0)[:, valid],
                    np.clip(np.diff(shot, axis=0, prepend=0.0)[:, valid], 0.0, None), valid)
    return parts, out


def _cross_misfit(params, response, cross):
    """The cross-read products' departures from the model with brighter-fatter
    ``params`` in units of their floor scatters: measured less (the floor plus
    what the kernel adds, :class:`~.ramp_cross.CrossResponse` ``response``)."""
    added = response.expected(kernel_from_deflection(
        params["deflection_x_at_50ke"], params["deflection_y_at_50ke"], params["reach"],
        params["upwind"]))
    return np.array([(cross["cross_read"][name] - cross["cross_read_floor"][name][0]
                      - added[name]) / cross["cross_read_floor"][name][1]
                     for name in CROSS_LAGS])


def fit_frame_effect(name, model, ramps, ln_n, max_nfev=40, cross=None):
    """``(params, evidence, new model, fit)`` of frame effect ``name`` added
    to ``model`` and fitted to ``ramps`` (module docstring); ``fit`` a
    :class:`~.fitting.FitResult` (``chi2`` the delta chi^2, ``cov`` from the
    whitened residuals' Jacobian) for :func:`signature_refusal`. ``cross``
    (the current model's :func:`~.ramps.ramp_gap` result): brighter-fatter's
    residuals include its cross-read products (:func:`_cross_misfit`) when
    the gap's mean square lies within 3 floor scatters of its floor."""
    start = model.frame.starting_params(name)
    keys = FITTED[name]
    specs = {p.name: p for p in EFFECTS[name].params}
    x0 = np.array([start[key] for key in keys], dtype=np.float64)
    scale = np.array([specs[key].scale for key in keys])
    lower = np.array([specs[key].lower for key in keys])
    upper = np.array([specs[key].upper for key in keys])
    use_cross = name == "brighter_fatter" and cross is not None and "cross_read" in cross and (
        # a mean the model misses makes every product large: the covariance
        # is read only where the mean square is at its floor
        abs(cross["gap"] - cross["gap_floor"]) <= 3.0 * cross["gap_floor_sigma"])
    parts, response = _parts(model, ramps, response=use_cross)
    size = sum(d.size for _, d, _ in parts) + (len(CROSS_LAGS) if use_cross else 0)

    def newer(x):
        params = {**start, **{key: float(v) for key, v in zip(keys, x)}}
        return RampModel(model.frame.with_effects({name: params}), model.effects, model.odd)

    def residual(z):
        try:
            trial = newer(x0 + z * scale)
            out = ([_cross_misfit(trial.frame.effects[name], response, cross)] if use_cross
                   else [])
            for k, (chol, d, valid) in enumerate(parts):
                mu = expected_mean(trial, ramps[k], trial.afterglow(ramps, k))
                out.append(whiten(chol, d - np.diff(mu, axis=0, prepend=0.0)[:, valid]).ravel())
            return np.concatenate(out)
        except (LawError, GeometryError, ValueError):
            return np.full(size, _FAILED)

    before = float(np.sum(residual(np.zeros(len(keys))) ** 2))
    lo, hi = (lower - x0) / scale, (upper - x0) / scale
    # an "off" value on a bound (a geometry term's 0) starts one scale inside:
    # from the bound itself the trust region's first step is 1e-10 and it stops
    fit = least_squares(residual, np.clip(0.0, lo + 1.0, hi - 1.0), bounds=(lo, hi),
                        diff_step=1e-3, max_nfev=max_nfev, x_scale=1.0)
    x = x0 + fit.x * scale
    gain = before - 2.0 * float(fit.cost)
    best = newer(x)
    cov = scale[:, None] * np.linalg.pinv(fit.jac.T @ fit.jac) * scale[None, :]
    fkeys = [(name, key) for key in keys]
    result = FitResult(best.frame, gain, dict(zip(fkeys, map(float, x))),
                       dict(zip(fkeys, np.sqrt(np.clip(np.diag(cov), 0.0, None)))), cov, fkeys,
                       int(fit.nfev))
    return best.frame.effects[name], gain - len(keys) * ln_n, best, result


def signature_refusal(name, fit):
    """Why the ramp fit ``fit`` of frame effect ``name`` is not that effect,
    or ``None``: its own signature under 5 sigma (:func:`~.gates.signature`,
    the frames' test: a rescaled coupling, ``weight_horizontal =
    weight_vertical``, is not anisotropy, nor a constant law with a new floor
    signal dependence)."""
    z2 = signature(name, fit)
    if z2 > SIGNATURE_Z2:
        return None
    return (f"its own signature is {math.sqrt(max(z2, 0.0)):.1f} sigma (needs "
            f"{math.sqrt(SIGNATURE_Z2):g}): what it fits is a rescaled coupling")


def rival_contradiction(name, evidence, threshold):
    """Why frame effect ``name`` is not the one that moves charge between
    neighbours, given ``evidence`` (``{name: delta BIC}`` of the effects
    fitted to the same increments), or ``None``: its rival fits the time
    structure better by more than ``threshold``, or neither is ahead by that
    much (the ramps do not tell them apart)."""
    if name not in RIVALS:
        return None
    other = RIVALS[1 - RIVALS.index(name)]
    if other not in evidence:
        return None
    lead = evidence[name] - evidence[other]
    if lead < -threshold:
        return (f"{other} fits the increments read by read better (delta BIC "
                f"{evidence[other]:.1f} against {evidence[name]:.1f})")
    if lead <= threshold:
        return (f"the ramps do not tell it from {other} (delta BIC {evidence[name]:.1f} "
                f"against {evidence[other]:.1f}, under {threshold:g} apart)")
    return None
