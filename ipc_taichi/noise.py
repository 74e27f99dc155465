"""Noise through the decoupler: the variance of each decoupled pixel.

The decoupler solves ``C(x) = y`` for the signal ``x`` (``C`` the forward
model of :func:`ipc_taichi.couple`, ``y`` the measured frame). Linearised about
the solution, a small change of the measured frame moves the answer by
``dx = G dy`` with ``G = J^{-1}`` and ``J = dC/dx`` the Jacobian of the coupling
at ``x``, including the derivatives of ``alpha(S, N)`` with respect to the
signals of both pixels of every pair (a signal-dependent law). Two kinds of
noise pass through it differently (``stage``):

``"readout"``
    Noise added after the coupling, independent from pixel to pixel: read
    noise (``VAR_RNOISE``), the flat-field error (``VAR_FLAT``, Roman's
    ``var_flat``), and whatever is not known to be shot noise.
    ``Var(x_i) = sum_j G_ij^2 Var(y_j)`` (independent pixels).
``"collected"``
    Shot noise of the collected charge (``VAR_POISSON``: photons, dark
    current). It arises before the coupling, so the decoupler undoes exactly
    the coupling that correlated it: ``x = D(C(S + dS)) = S + dS`` whatever
    the law, and the decoupled pixel carries its own shot noise only, with no
    correlation. A Poisson variance estimated from the coupled signal (as the
    pipelines estimate ``VAR_POISSON`` from the measured slope) is moved with
    the charge the decoupler moves: ``Var(x_i) = max(Var(y_i) + c (x_i - y_i),
    0)`` in electrons, ``c`` the frame's variance per electron of charge
    (``sum Var(y) / sum y`` over pixels with ``y > 0``: 1 for a Poisson
    variance of the law's charge). One ``c`` per frame keeps this stable where
    the signal is near zero. Propagating shot noise as ``"readout"`` instead
    would overstate it by about ``8 alpha`` on a flat field (12 % in variance
    for the paper's law, ``docs/noise.md``).

How ``G`` is found
------------------
``J`` is assembled pair by pair from the law's own NumPy ``alpha`` (its
partial derivatives by central differences), with the coupling's rules for
edges and masked pixels; the tests check it against finite differences of
:func:`ipc_taichi.couple`. The rows of ``G`` are then probed: the pixels are
coloured so that two pixels of one colour are at least ``2 reach + 1``
coupling steps apart, and ``J z = b_c`` is solved for each colour's indicator
``b_c`` by the Jacobi iteration ``z <- D^{-1} (b_c - N z)`` (``J = D + N``),
which is the Neumann series of ``(D^{-1} J)^{-1}`` truncated after ``K`` terms.
Its truncation error is bounded by ``rho^(K+1) / (1 - rho) / min D`` with
``rho`` the largest row sum of ``|D^{-1} N|`` (``K`` is chosen to bring it
below ``tol``). ``z_c[i]`` is then ``G_ij`` for the pixel ``j`` of colour
``c`` nearest ``i`` plus entries of ``G`` at least ``reach + 1`` steps away
(``~alpha^(reach+1)``); for the paper's law and the 4 nearest neighbours,
5 colours (``reach=1``) leave errors below 1e-3 of the variance (4e-4 measured
against a dense inverse), 13 colours (``reach=2``) below 1e-5. Frames are
done in bands of rows with a halo the Neumann terms cannot cross (the same
answer, bounded memory).

Units
-----
``variance`` is in (data units)^2, ``solution`` and ``measured`` in data
units; ``scale`` is the product's electrons per data unit (its
``charge_scale``: gain, times the integration time for a rate, divided by
coadds). The law sees the charge ``solution * scale (+ pedestal)`` in
electrons; variances are propagated in electrons^2 and returned in
(data units)^2.

Masked pixels
-------------
As in the decoupler, a masked pixel (``mask``, a non-finite solution, or no
usable ``scale``) neither gives nor takes charge and keeps its measured value:
its variance is returned unchanged and it adds nothing to its neighbours'.
The exchange between a neighbour and a masked pixel stays in the neighbour,
in the signal as in its variance. A non-finite variance on an unmasked pixel
makes its neighbours' variance non-finite too (they depend on it).

Correlations
------------
Decoupling makes the read noise of neighbouring pixels anti-correlated: white
read noise of variance ``V`` comes out with variance ``1.13 V`` and a nearest
neighbour covariance of ``-2.4 alpha V`` (a correlation of -3.1 %) for a
constant ``alpha = 1.45 %``. Shot noise, correlated by the coupling in the
measured frame (``+2 alpha``), comes out uncorrelated. Products that carry
per-pixel variances only cannot hold this;
:meth:`Linearisation.neighbour_covariance` gives the covariance of each pixel
with its 8 neighbours.
"""

from dataclasses import dataclass

import numpy as np

from .errors import IPCInputError
from .jacobian import rows_of_g
from .model import CouplingModel

__all__ = ["METHOD", "STAGES", "TOL", "NEIGHBOUR_OFFSETS", "Linearisation", "linearise",
           "propagate_variance", "propagate_error", "propagate_noise", "neighbour_covariance"]

METHOD = "linearised decoupler J^-1, indep. pixels; shot noise follows charge"
"""What the products write (keyword ``IPCNOISE``): at most 68 characters."""

STAGES = ("readout", "collected")
"""Where a noise arises: after the coupling (``readout``) or in the collected
charge before it (``collected``)."""

TOL = 1e-6
"""Default bound on the truncation error of each probed row of ``G``."""

_NEIGHBOURS = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))


@dataclass
class Linearisation:
    """``G = J^{-1}`` of the coupling at a decoupled frame, row by row.

    Build it with :func:`linearise`. ``stencil[k][i] = G[i, i + offsets[k]]``.

    Attributes
    ----------
    offsets : list of (dy, dx)
    stencil : ndarray (len(offsets), ny, nx)
    valid : ndarray of bool (ny, nx)
        Pixels that took part (the others keep their variance).
    scale : float or ndarray
        Electrons per data unit.
    contraction : float
        ``rho``: the largest row sum of ``|D^{-1} N|``.
    terms : int
        Jacobi steps per colour (Neumann terms after the first).
    bound : float
        Bound on the truncation error of each entry of ``stencil``.
    """

    offsets: list
    stencil: np.ndarray
    valid: np.ndarray
    scale: object
    contraction: float
    terms: int
    bound: float

    def variance(self, variance, stage="readout", measured=None, solution=None):
        """Propagate one per-pixel variance array (data units^2) to the decoupled frame.

        Parameters
        ----------
        variance : ndarray (ny, nx)
            Variance of the measured frame, (data units)^2.
        stage : {"readout", "collected"}
            Where the noise arises (module docstring).
        measured, solution : ndarray (ny, nx)
            The frame that was decoupled and the answer, data units; needed
            for ``"collected"``.

        Returns
        -------
        ndarray (ny, nx), float64, (data units)^2
        """
        v = np.asarray(variance, dtype=np.float64)
        self._check(v, "variance")
        if stage == "collected":
            if measured is None or solution is None:
                raise IPCInputError("stage 'collected' needs the measured frame and the solution")
            return _shot_moved(v, np.asarray(measured, float), np.asarray(solution, float),
                               self.valid, self.scale)
        if stage != "readout":
            raise IPCInputError(f"stage must be one of {', '.join(STAGES)}, got {stage!r}")
        s2 = np.square(self.scale)
        ve = np.where(self.valid, v * s2, 0.0)
        out = np.zeros(v.shape)
        for g, shifted in zip(self.stencil, self._shifted(ve)):
            out += np.square(g, dtype=np.float64) * shifted
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.valid, out / s2, v)

    def error(self, err, var_poisson=None, measured=None, solution=None):
        """Propagate an error array (data units): ``err^2 - var_poisson`` as
        ``"readout"`` noise, ``var_poisson`` (if given) as ``"collected"``.

        Without ``var_poisson`` all of ``err^2`` is taken as readout noise,
        which overstates the shot-noise part by about ``8 alpha``.
        """
        e2 = np.square(np.asarray(err, dtype=np.float64))
        if var_poisson is None:
            return np.sqrt(self.variance(e2))
        vp = np.asarray(var_poisson, dtype=np.float64)
        rest = np.maximum(e2 - vp, 0.0)
        total = (self.variance(rest)
                 + self.variance(vp, "collected", measured=measured, solution=solution))
        return np.where(self.valid, np.sqrt(total), np.asarray(err, dtype=np.float64))

    def neighbour_covariance(self, variance):
        """Covariance of each decoupled pixel with its 8 neighbours, readout noise.

        ``cov[k][i] = Cov(x_i, x_(i + d_k))`` for ``d_k`` in
        :data:`NEIGHBOUR_OFFSETS`, (data units)^2, from ``sum_j G_ij G_(i+d),j
        Var(y_j)`` over the entries this linearisation holds (build it with
        ``reach=2``: with ``reach=1`` the diagonal terms lack the entries two
        steps away). Shot noise (``"collected"``) comes out uncorrelated;
        pixels next to the frame edge have 0 towards the outside; masked
        pixels 0.
        """
        v = np.asarray(variance, dtype=np.float64)
        self._check(v, "variance")
        ve = np.where(self.valid, v * np.square(self.scale), 0.0)
        ny, nx = v.shape
        pad = max(max(abs(a), abs(b)) for a, b in self.offsets) + 1
        index = {o: k for k, o in enumerate(self.offsets)}
        gp = np.zeros((len(self.offsets), ny + 2 * pad, nx + 2 * pad))
        gp[:, pad:pad + ny, pad:pad + nx] = self.stencil
        vp = np.zeros((ny + 2 * pad, nx + 2 * pad))
        vp[pad:pad + ny, pad:pad + nx] = ve
        scale = np.broadcast_to(np.asarray(self.scale, float), (ny, nx))
        sp = np.ones((ny + 2 * pad, nx + 2 * pad))
        sp[pad:pad + ny, pad:pad + nx] = scale
        ok = np.zeros((ny + 2 * pad, nx + 2 * pad), bool)
        ok[pad:pad + ny, pad:pad + nx] = self.valid

        def at(a, oy, ox):
            return a[..., pad + oy:pad + oy + ny, pad + ox:pad + ox + nx]

        cov = np.zeros((len(_NEIGHBOURS), ny, nx))
        for k, (dy, dx) in enumerate(_NEIGHBOURS):
            for o, i in index.items():
                j = index.get((o[0] - dy, o[1] - dx))
                if j is not None:
                    cov[k] += self.stencil[i] * at(gp[j], dy, dx) * at(vp, *o)
            with np.errstate(divide="ignore", invalid="ignore"):
                cov[k] = np.where(self.valid & at(ok, dy, dx),
                                  cov[k] / (scale * at(sp, dy, dx)), 0.0)
        return cov

    def _shifted(self, values):
        """``values[i + o]`` for each offset (zero outside the frame)."""
        ny, nx = values.shape
        pad = max(max(abs(a), abs(b)) for a, b in self.offsets)
        padded = np.zeros((ny + 2 * pad, nx + 2 * pad))
        padded[pad:pad + ny, pad:pad + nx] = values
        for oy, ox in self.offsets:
            yield padded[pad + oy:pad + oy + ny, pad + ox:pad + ox + nx]

    def _check(self, v, what):
        if v.shape != self.valid.shape:
            raise IPCInputError(f"{what} of shape {v.shape} does not fit the frame "
                                f"{self.valid.shape}")


NEIGHBOUR_OFFSETS = _NEIGHBOURS
"""The 8 offsets ``(dy, dx)`` of :meth:`Linearisation.neighbour_covariance`, in order."""


def _shot_moved(v, measured, solution, valid, scale):
    """A shot-noise variance estimated on the coupled signal moved to the decoupled
    one: ``v + c (x - y)`` in electrons, ``c`` the frame's variance per electron."""
    s = np.broadcast_to(np.asarray(scale, dtype=np.float64), v.shape)
    with np.errstate(invalid="ignore", over="ignore"):
        ve, ye, xe = v * s * s, measured * s, solution * s
        use = valid & np.isfinite(ve) & np.isfinite(ye) & (ye > 0)
        total = float(ye[use].sum())
        per_electron = float(ve[use].sum()) / total if total > 0 else 0.0
        moved = np.maximum(ve + per_electron * (xe - ye), 0.0) / (s * s)
    return np.where(valid & np.isfinite(moved), moved, v)


def linearise(solution, model=None, *, mask=None, scale=1.0, pedestal=None, edge=None,
              reach=1, tol=TOL):
    """Linearise the decoupler at a decoupled frame: the rows of ``G = J^{-1}``.

    Parameters
    ----------
    solution : ndarray (ny, nx)
        The decoupled frame, data units (what :func:`ipc_taichi.decouple`
        returned, divided by ``scale``).
    model : CouplingModel, str, path or None
        As ``model=`` of :func:`ipc_taichi.decouple` (a law name is taken as
        ``law=``); ``None``: the paper's model.
    mask : ndarray of bool, optional
        The pixels the decoupler was told to leave out.
    scale : float or ndarray (ny, nx)
        Electrons per data unit (the product's charge scale); pixels where it
        is not finite and positive are left out, as the products do.
    pedestal : ndarray (ny, nx), optional
        Charge on the node before the first read, electrons: the law is
        evaluated at ``solution * scale + pedestal`` (the products decouple
        ``D(M + P) - D(P)``; using ``P`` for ``D(P)`` here changes ``J`` only
        through the pedestal's own coupling, a second-order effect).
    edge : {"zero", "isolated"}, optional
        Overrides the model's edge rule (as the products choose it).
    reach : int
        Entries of ``G`` kept exactly out to this many coupling steps: 1 for
        variances, 2 for :meth:`Linearisation.neighbour_covariance`.
    tol : float
        Bound on the truncation error of each entry of ``G``.

    Returns
    -------
    Linearisation
    """
    model = _model(model, edge)
    x = np.asarray(solution, dtype=np.float64)
    if x.ndim != 2:
        raise IPCInputError(f"solution must be one 2-D frame, got shape {x.shape}")
    s = np.broadcast_to(np.asarray(scale, dtype=np.float64), x.shape)
    valid = np.isfinite(x) & np.isfinite(s) & (s > 0)
    if mask is not None:
        valid &= ~np.broadcast_to(np.asarray(mask, bool), x.shape)
    charge = np.where(valid, x * s, 0.0)
    if pedestal is not None:
        charge = charge + np.where(valid, np.asarray(pedestal, dtype=np.float64), 0.0)
    offsets, stencil, rho, terms, bound = rows_of_g(charge, model, valid, reach, tol)
    scale_out = float(scale) if np.ndim(scale) == 0 else np.asarray(scale, dtype=np.float64)
    return Linearisation(offsets, stencil, valid, scale_out, rho, terms, bound)


def _model(model, edge):
    if model is None or isinstance(model, CouplingModel):
        m = CouplingModel.resolve(model=model)
    elif isinstance(model, str) and not model.endswith(".json"):
        m = CouplingModel.resolve(law=model)
    else:
        m = CouplingModel.resolve(model=model)
    if edge is not None and edge != m.edge:
        m = CouplingModel.resolve(m.law, m.geometry, edge)
    return m


def _frames(solution, *arrays):
    """Iterate 2-D frames of a frame or a stack (``None`` arrays stay ``None``)."""
    x = np.asarray(solution)
    if x.ndim == 2:
        yield (x,) + tuple(arrays)
        return
    for k in range(x.shape[0]):
        yield (x[k],) + tuple(a if a is None or np.ndim(a) < 3 else np.asarray(a)[k]
                              for a in arrays)


def propagate_variance(variance, solution, model=None, *, stage="readout", measured=None,
                       mask=None, scale=1.0, pedestal=None, edge=None, tol=TOL):
    """The variance of each decoupled pixel, (data units)^2.

    ``variance``, ``solution`` (and ``measured``) are one frame (ny, nx) or a
    stack (n, ny, nx) decoupled frame by frame (e.g. the groups of a ramp);
    ``mask`` and ``pedestal`` a frame or a stack, ``scale`` a number or a
    frame. ``stage`` as in :meth:`Linearisation.variance`; the other
    arguments as for :func:`linearise`. Masked pixels keep their variance.
    """
    out = []
    for x, v, y, m, p in _frames(solution, variance, measured, mask, pedestal):
        lin = linearise(x, model, mask=m, scale=scale, pedestal=p, edge=edge, tol=tol)
        out.append(lin.variance(v, stage, measured=y, solution=x))
    return out[0] if np.ndim(solution) == 2 else np.stack(out)


def propagate_error(err, solution, model=None, *, var_poisson=None, measured=None, mask=None,
                    scale=1.0, pedestal=None, edge=None, tol=TOL):
    """The error (standard deviation) of each decoupled pixel, data units.

    ``err**2 - var_poisson`` is propagated as readout noise and
    ``var_poisson`` (if given, with ``measured``) as shot noise
    (:meth:`Linearisation.error`); arguments as for :func:`propagate_variance`.
    """
    out = []
    for x, e, vp, y, m, p in _frames(solution, err, var_poisson, measured, mask, pedestal):
        lin = linearise(x, model, mask=m, scale=scale, pedestal=p, edge=edge, tol=tol)
        out.append(lin.error(e, vp, measured=y, solution=x))
    return out[0] if np.ndim(solution) == 2 else np.stack(out)


def propagate_noise(solution, model=None, *, measured=None, err=None, var_poisson=None,
                    var_rnoise=None, var_flat=None, mask=None, scale=1.0, pedestal=None,
                    edge=None, tol=TOL):
    """A product's noise arrays for one decoupled frame, with one linearisation.

    Parameters
    ----------
    solution, measured : ndarray (ny, nx)
        The decoupled frame and the frame that was decoupled, data units.
    err : ndarray, optional
        ``ERR`` / ``err`` (data units). Recomposed from the propagated
        variances: ``err^2`` minus the variances given (the remainder, if any,
        as readout noise) plus their propagated values.
    var_poisson : ndarray, optional
        Shot noise, ``"collected"`` (needs ``measured``).
    var_rnoise, var_flat : ndarray, optional
        Read noise and flat-field variance, ``"readout"``.
    mask, scale, pedestal, edge, tol :
        As for :func:`linearise`.

    Returns
    -------
    dict
        The propagated arrays under the names given (``"err"``,
        ``"var_poisson"``, ``"var_rnoise"``, ``"var_flat"``).
    """
    lin = linearise(solution, model, mask=mask, scale=scale, pedestal=pedestal, edge=edge,
                    tol=tol)
    out, before, after = {}, 0.0, 0.0
    for name, v, stage in (("var_poisson", var_poisson, "collected"),
                           ("var_rnoise", var_rnoise, "readout"),
                           ("var_flat", var_flat, "readout")):
        if v is not None:
            out[name] = lin.variance(v, stage, measured=measured, solution=solution)
            before = before + np.asarray(v, dtype=np.float64)
            after = after + out[name]
    if err is not None:
        e = np.asarray(err, dtype=np.float64)
        rest = lin.variance(np.maximum(np.square(e) - before, 0.0))
        out["err"] = np.where(lin.valid, np.sqrt(rest + after), e)
    return out


def neighbour_covariance(variance, solution, model=None, *, mask=None, scale=1.0,
                         pedestal=None, edge=None, tol=TOL):
    """Covariance of each decoupled pixel with its 8 neighbours for readout noise:
    ``(8, ny, nx)`` in the order of :data:`NEIGHBOUR_OFFSETS`, (data units)^2
    (:meth:`Linearisation.neighbour_covariance`, with ``reach=2``)."""
    lin = linearise(solution, model, mask=mask, scale=scale, pedestal=pedestal, edge=edge,
                    reach=2, tol=tol)
    return lin.neighbour_covariance(variance)

