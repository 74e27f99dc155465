"""Flat ramps: gain, classical non-linearity, IPC and brighter-fatter told apart in time.

A flat ramp is read non-destructively at equally spaced reads ``k = 0 .. G-1``
(read 0 the first after reset, collected charge ~0 plus an unknown bias); the
mean collected charge at read ``k`` is ``Qbar_k = I k`` (``I`` [e-/group]).
Three effects make flat covariances depend on signal, and they act at
different moments:

- **IPC** (and its signal dependence, non-linear IPC) and **classical
  non-linearity** act on the charge present *at the read*. On a flat of level
  ``Q`` the readout's Jacobian is ``J(Q) = (1 - 2 beta Q) K(Q)``, with ``K`` the
  symmetric 5x5 coupling kernel whose off-centre entries are the five terms
  ``k_t(Q) = k_t0 + k_t1 Q`` of :data:`~ipc_taichi.calibrate.flats.TERMS` (the
  ``w(d) alpha(S, S)`` of a flat at ``S = Q``) and whose centre is ``1 - sum``;
  the measured charge is ``M = Q' - beta Q'^2`` of the coupled charge ``Q'``.
- **Brighter-fatter** acts *while charge is collected*: pixel ``p`` collects at
  the rate ``I (1 + sum_d a(d) Q(p + d))`` (``a`` a symmetric 5x5 kernel per
  electron, ``sum a = 0``, ``a(0, 0) < 0``), so a fluctuation of charge, once
  collected, keeps steering the later collection of its neighbours.

The fixed pattern (pixel response) is cancelled by subtracting, per pixel and
increment, the mean over integrations (scaled by ``sqrt(n / (n - 1))``); the
spatial mean of each increment is removed too (illumination changes between
integrations). With a single integration nothing can be subtracted: a
pattern ``eps`` of the collection rate adds ``I^2 P`` to every pair of
increments (``P`` its autocorrelation after the readout), the time structure
of brighter-fatter, and brighter-fatter acting on the pattern adds
``I^3 (a*P) (k + l + 1)``. The fit then replaces brighter-fatter by a free
common term ``A(delta) + B(delta) (k + l + 1)`` for every pair ``k <= l``
(which also absorbs brighter-fatter itself to first order); IPC and its
signal dependence stay separate from it (the same-increment covariances
against the pairs of different increments), brighter-fatter is not measured.

The sufficient statistics are additive: per spatial block, the sums over
pixels and integrations of ``d_k(p) d_l(p + delta)`` for every pair of
increments and the 13 lags :data:`LAGS` (one matrix product over the pixel
axis per lag), with their counts. The joint fit (weighted least squares, the
weights of each covariance ``sqrt(n / (C_kk(0) C_ll(0) + C_kl^2))``) gives
the gain ratio, the read noise, ``k_t0``, ``k_t1`` and ``a``; every error is a
jackknife over the spatial blocks (each block left out in turn, the mean ramp
and the fit redone), never a formula. Per-level points (:meth:`FlatRamps.levels`)
are covariances with everything but ``(I/r) J*J`` removed (brighter-fatter,
read noise), solved for the kernel at their level exactly as a flat at one
level (:func:`~ipc_taichi.calibrate.flats.solve_kernel`): by default the
same-increment covariances of disjoint windows of increments (independent
points; brighter-fatter only a few % of them), or the covariances of
``D_b = M_b - M_0`` (what a flat at ``Qbar_b`` sees; correlated points, and
at the top of a ramp the brighter-fatter term removed is as large as the
IPC term).

This module holds the orchestration (:class:`FlatRamps`: which blocks, which
fits, the cache, the public record); the seams are :mod:`.rampsums` (ramps
into sums per block), :mod:`.rampmodel` (the covariance model) and
:mod:`.rampfit` (the joint fit, its jackknife errors, its reports and the
per-level points).
"""

import numpy as np

from ..errors import IPCInputError
from . import stream
from .flats import TERMS
from .rampfit import (
    bf_report,
    fit_increments,
    internal_params,
    ipc_report,
    jackknife,
    jackknife_errors,
    level_note,
    level_point,
    nonlinear_ipc_report,
    nonlinearity_report,
    public_params,
    read_noise_report,
)
from .rampmodel import (
    LAGS,
    SYMMETRIC_LAGS,
    VARIANTS,
    RampCovariance,
    kernel_from_symmetric,
    mean_ramp,
    symmetric_from_kernel,
    variant_fixed,
    with_zero_sum,
)
from .rampsums import block_sums, symmetrise

__all__ = ["FlatRamps", "LAGS", "SYMMETRIC_LAGS", "VARIANTS", "kernel_from_symmetric",
           "symmetric_from_kernel"]


class FlatRamps:
    """Sufficient statistics of flat ramps at one illumination (per spatial block).

    Build with :meth:`from_ramps`; :meth:`measure` fits gain ratio, read
    noise, classical non-linearity, IPC (constant and signal-dependent) and
    brighter-fatter jointly; :meth:`levels` gives per-level kernels with
    brighter-fatter removed; :meth:`predict` gives model curves for figures.

    Attributes
    ----------
    n_blocks : int
        Number of spatial blocks.
    n_integrations : int
        Integrations (ramps) combined.
    n_groups : int
        Reads used per ramp (those below the saturation level).
    current : float
        ``I``, mean collected charge per group [e-/group], from the mean ramp.
    notes : list of str
        What was dropped or assumed while reading.
    """

    def __init__(self, sums, counts, increment_sums, n_pixels, n_integrations, notes=(),
                 collection_steps=None):
        self._sums = np.asarray(sums, dtype=np.float64)
        self._counts = np.asarray(counts, dtype=np.float64)
        self._increments = np.asarray(increment_sums, dtype=np.float64)
        self._pixels = np.asarray(n_pixels, dtype=np.float64)
        self.n_blocks = int(self._sums.shape[0])
        self.n_integrations = int(n_integrations)
        self.n_groups = int(self._sums.shape[-1]) + 1
        self.notes = list(notes)
        self.collection_steps = None if not collection_steps else int(collection_steps)
        current, _ = mean_ramp(self._increments.sum(axis=(0, 1)),
                               self._pixels.sum() * self.n_integrations)
        self.current = float(current)
        self._cache = {}

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_ramps(cls, ramps, mask=None, *, border=2, blocks=(4, 4), saturation=None,
                   collection_steps=None):
        """Sums of products of increments of flat ramps, per spatial block.

        Parameters
        ----------
        ramps : ndarray, (nints, ngroups, ny, nx)
            Flat ramps at one illumination [e-, with the assumed gain]; a 3-D
            cube is one integration.
        mask : ndarray of bool, same shape or (ny, nx), optional
            True where a read is bad. A pixel masked (or non-finite) in any used
            read is left out of every product it touches.
        border : int
            Pixels dropped at each frame edge.
        blocks : (int, int)
            Spatial blocks (rows, columns) for the jackknife.
        saturation : float, optional
            Level [e-, as in ``ramps``] at or above which a read is not used:
            reads are used up to the last one where at most 1 % of the pixels
            reach it; a pixel reaching it in a used read is left out.
        collection_steps : int, optional
            None (default): charge is collected continuously (a detector).
            An integer: the ramps come from a simulator that collects each group
            in that many discrete steps, each at the rate set by the charge at its
            start (solid-waffle's ``SUBSTEPS``); the brighter-fatter response is
            then modelled step by step.

        Returns
        -------
        FlatRamps
        """
        data = ramps if stream.is_lazy(ramps) else np.asarray(ramps)
        if data.ndim == 3:
            data = data[None]
        if data.ndim != 4:
            raise IPCInputError(f"flat ramps are (nints, ngroups, ny, nx), got {data.shape}")
        sums, counts, inc_sums, n_pixels, notes = block_sums(data, mask, border, blocks,
                                                             saturation)
        return cls(sums, counts, inc_sums, n_pixels, data.shape[0], notes, collection_steps)

    # ------------------------------------------------------------------ data
    def _block_list(self, blocks):
        if blocks is None:
            return tuple(range(self.n_blocks))
        out = tuple(sorted({int(b) for b in blocks}))
        if not out or out[0] < 0 or out[-1] >= self.n_blocks:
            raise IPCInputError(f"blocks must be indices in 0..{self.n_blocks - 1}, got {blocks}")
        return out

    def _data(self, blocks):
        """Summed statistics of ``blocks``: symmetric covariances (9, G', G'),
        counts (9,), mean increments' sums (nints, G'), pixels."""
        sel = list(blocks)
        return symmetrise(self._sums[sel].sum(axis=0), self._counts[sel].sum(axis=0)) + (
            self._increments[sel].sum(axis=0), self._pixels[sel].sum())

    def _samples(self, blocks):
        """The data of ``blocks`` and of each leave-one-out subset."""
        full = self._data(blocks)
        if len(blocks) < 3:
            return full, []
        return full, [self._data([b for b in blocks if b != out]) for out in blocks]

    def covariances(self, blocks=None):
        """Measured covariances of the increments, symmetrised.

        Parameters
        ----------
        blocks : sequence of int, optional
            Spatial blocks (all when None).

        Returns
        -------
        dict
            ``lags`` (:data:`SYMMETRIC_LAGS`); ``cov`` ndarray (9, G-1, G-1)
            [e-^2]: ``cov[c, k, l]`` the mean of ``d_k(p) d_l(p + delta)`` over
            pixels, integrations, both orders of the pair and the reflections of
            lag ``c`` (fixed pattern and spatial mean removed); ``pairs`` (9,):
            pixel pairs (times integrations) per lag and order.
        """
        cov, pairs, _, _ = self._data(self._block_list(blocks))
        return {"lags": SYMMETRIC_LAGS, "cov": cov, "pairs": pairs}

    # ------------------------------------------------------------------ fitting
    def _fit(self, data, fixed, start=None, read_noise=None):
        return fit_increments(data, fixed, self.n_groups, self.n_integrations,
                              self.collection_steps, start, read_noise)

    def _fits(self, blocks, read_noise, bf_values=None, variant="full"):
        """Full and leave-one-out fits of ``blocks`` (cached)."""
        key = (blocks, read_noise, None if bf_values is None else tuple(bf_values), variant)
        if key not in self._cache:
            fixed = variant_fixed(variant, self.n_integrations)
            if bf_values is not None:
                fixed["a"] = np.asarray(bf_values, dtype=np.float64)
            full_data, loo = self._samples(blocks)
            full = self._fit(full_data, fixed, read_noise=read_noise)
            start = {k: full[k] for k in ("r", "s2", "k0", "k1", "a", "common")}
            jack = [self._fit(d, fixed, start=start, read_noise=read_noise) for d in loo] \
                if variant == "full" else []
            self._cache[key] = (full_data, full, loo, jack)
        return self._cache[key]

    # ------------------------------------------------------------------ public
    def measure(self, blocks=None, read_noise=None):
        """Joint fit of gain ratio, read noise, non-linearity, IPC and brighter-fatter.

        Parameters
        ----------
        blocks : sequence of int, optional
            Spatial blocks to use (all when None); the errors are a jackknife over
            them (at least 3 are needed for errors).
        read_noise : float, optional
            Read noise per read [e-]; fitted when None.

        Returns
        -------
        dict
            ``gain_ratio`` {value, error} (true electrons per electron of the
            data: the measured gain is the assumed one times ``value``);
            ``current`` [e-/group]; ``read_noise`` {value, error, source} [e-
            per read]; ``classical_nonlinearity`` {measured, beta, error,
            significance, detected, form}; ``brighter_fatter`` {measured,
            detected, significance (nearest terms over their error),
            kernel, kernel_error (5x5 [2 + dy][2 + dx], 1/e-), chi2, chi2_sigma,
            note}; ``ipc`` {terms: {term: {value (at zero charge), error,
            slope_per_10ke, slope_error}}}; ``nonlinear_ipc`` {detected,
            significance (slope of x + y over its error), slope_per_10ke,
            error, note}; ``chi2_per_dof``; ``n_pixels``; ``covariance_curves``
            (same-increment ``C_kk(delta) / (I/r)`` against ``Qbar_{k+1}``:
            measured with errors and each variant refitted); ``params`` (for
            :meth:`predict`); ``variants`` (each refitted: ``chi2_per_dof``,
            ``params``); ``notes``. Detection: significance >= 5.
        """
        blocks = self._block_list(blocks)
        full_data, full, loo, jack = self._fits(blocks, read_noise)
        out = {"current": full["current"], "n_pixels": int(full_data[3]),
               "n_integrations": self.n_integrations, "n_groups": self.n_groups,
               "chi2_per_dof": full["chi2_per_dof"], "notes": list(self.notes)}
        errors = jackknife_errors(jack)
        if not jack:
            out["notes"].append("fewer than 3 blocks: no jackknife, errors unknown")
        out["gain_ratio"] = {"value": float(full["r"]), "error": errors("r")}
        out["read_noise"] = read_noise_report(full, errors, read_noise)
        out["classical_nonlinearity"] = nonlinearity_report(full, jack, errors,
                                                            self._integration_betas(blocks))
        out["ipc"] = ipc_report(full, errors)
        out["nonlinear_ipc"] = nonlinear_ipc_report(full, jack, self.n_integrations)
        out["brighter_fatter"] = bf_report(full, jack, self.n_integrations)
        variants = {v: self._fits(blocks, read_noise, variant=v)[1] for v in VARIANTS}
        out["params"] = public_params(full, self.n_groups)
        out["variants"] = {v: {"chi2_per_dof": p["chi2_per_dof"],
                               "params": public_params(p, self.n_groups)}
                           for v, p in variants.items()}
        out["covariance_curves"] = self._curves(full_data, loo, full, out["variants"])
        return out

    def levels(self, blocks=None, bf_kernel=None, read_noise=None, method="increments"):
        """Per-level kernels ``alpha(S, S) w(d)`` with brighter-fatter removed.

        Parameters
        ----------
        blocks : sequence of int, optional
            Spatial blocks (all when None); errors by the jackknife over them
            (each left-out block with its own fit).
        bf_kernel : array_like (5, 5), optional
            Brighter-fatter kernel [1/e-] to remove (its symmetric part); default:
            the one :meth:`measure` finds on the same blocks. With one
            integration the common term of brighter-fatter and the fixed
            pattern, fitted beside IPC, is removed instead (and ``bf_kernel``
            is not used).
        read_noise : float, optional
            Read noise per read [e-]; fitted when None.
        method : {"increments", "difference"}
            ``difference``: for about eight reads ``b`` spread over the ramp, the
            covariance of ``D_b = M_b - M_0`` (from the same sums) minus its
            brighter-fatter term and ``2 sigma^2`` at lag 0, at ``Qbar_b = I b``:
            what a flat at level ``Qbar_b`` would give, but the points share
            their increments (correlated) and the brighter-fatter term removed
            grows to the size of the IPC term itself at the top of a ramp.
            ``increments``: about eight disjoint windows of consecutive
            increments; each window's same-increment covariances minus their
            brighter-fatter term (``I^2 J*J*a``, a few % of the IPC term) and
            ``2 sigma^2``, at the mean ``Qbar_{k+1}`` of the window: independent
            points, nearly free of the brighter-fatter model (the default: a law
            fitted to the points may treat them as independent).

        Returns
        -------
        list of dict
            ``level`` [e-], ``terms`` {term: {value, error}}, ``V`` (shot
            variance [e-^2] of ``D_b``, or of one increment of the window),
            ``poisson_ratio`` (``V`` over the mean charge it holds:
            ``(1 - 2 beta level)^2 / r``), ``reads`` (the reads used), ``notes``.
        """
        if method not in ("difference", "increments"):
            raise IPCInputError(f"method must be 'difference' or 'increments', got {method!r}")
        blocks = self._block_list(blocks)
        given = bf_kernel is not None and self.n_integrations > 1
        values = symmetric_from_kernel(bf_kernel) if given else None
        if values is not None:
            values = with_zero_sum(values)
        full_data, full, loo, jack = self._fits(blocks, read_noise, values)
        notes = [level_note(self.n_integrations, given)]
        n_inc = self.n_groups - 1
        if method == "difference":
            picks = [np.arange(b) for b in np.unique(np.round(
                np.linspace(n_inc / 8, n_inc, min(8, n_inc)))).astype(int)]
        else:
            picks = [w for w in np.array_split(np.arange(n_inc), min(8, n_inc)) if w.size]
        rows = []
        for inc in picks:
            point = level_point(full_data, full, self.n_groups, inc, method)
            samples = [level_point(d, p, self.n_groups, inc, method)
                       for d, p in zip(loo, jack, strict=True)]
            samples = [s for s in samples if s is not None]
            level = float(full["current"] * (inc.size if method == "difference"
                                             else np.mean(inc + 1)))
            reads = [0, int(inc.size)] if method == "difference" else [int(inc[0]),
                                                                        int(inc[-1] + 1)]
            if point is None:
                rows.append({"level": level, "reads": reads, "terms": None,
                             "problem": "no shot noise left", "notes": notes})
                continue
            err = np.sqrt(np.diag(jackknife([s[1] for s in samples]))) \
                if len(samples) >= 3 else np.full(5, np.nan)
            mean_charge = level if method == "difference" else full["current"]
            rows.append({"level": level, "reads": reads,
                         "terms": {t: {"value": float(point[1][i]), "error": float(err[i])}
                                   for i, t in enumerate(TERMS)},
                         "V": float(point[0]), "poisson_ratio": float(point[0] / mean_charge),
                         "notes": notes})
        return rows

    def predict(self, params, delta, variant):
        """Model same-increment covariances for figures.

        Parameters
        ----------
        params : dict
            ``measure()["params"]`` (or a variant's ``params``).
        delta : (int, int)
            Lag ``(dy, dx)`` (signs ignored: the model is symmetric).
        variant : str
            One of :data:`VARIANTS`: ``ipc_only`` drops the signal dependence of
            IPC and brighter-fatter, ``nonlinear_ipc`` drops brighter-fatter,
            ``brighter_fatter`` drops the signal dependence, ``full`` keeps all.

        Returns
        -------
        dict
            ``level``: ``Qbar_{k+1}`` [e-] for each increment ``k``;
            ``value``: ``C_kk(delta) / (I / r)`` (dimensionless).
        """
        if variant not in VARIANTS:
            raise IPCInputError(f"variant must be one of {VARIANTS}, got {variant!r}")
        p = internal_params(params)
        for name, value in variant_fixed(variant, 2).items():
            p[name] = value
        model = RampCovariance(int(params["n_groups"]), p["current"], p["beta"], p["steps"])
        lag = SYMMETRIC_LAGS.index((abs(int(delta[0])), abs(int(delta[1]))))
        same = np.diagonal(model.increments(p)[:, :, lag])
        return {"level": model.level[1:].copy(), "value": same * p["r"] / p["current"]}

    # ------------------------------------------------------------------ helpers
    def _integration_betas(self, blocks):
        """``beta`` of each integration's mean ramp (for the non-linearity error)."""
        if self.n_integrations < 3:
            return None
        sel = list(blocks)
        return mean_ramp(self._increments[sel].sum(axis=0), self._pixels[sel].sum())[1]

    def _curves(self, full_data, loo, full, variants):
        """Same-increment normalised covariances, measured and per variant."""
        norm = full["r"] / full["current"]
        level = full["current"] * np.arange(1, self.n_groups)
        out = {"level": level.tolist(), "normalisation": "C_kk(delta) / (I / r)",
               "chi2_per_dof": {v: variants[v]["chi2_per_dof"] for v in VARIANTS}, "lags": {}}
        for c, (dy, dx) in enumerate(SYMMETRIC_LAGS):
            measured = np.diagonal(full_data[0][c]) * norm
            if loo:
                err = np.sqrt(np.diag(jackknife([np.diagonal(d[0][c]) * norm for d in loo])))
            else:
                err = np.full(measured.shape, np.nan)
            row = {"measured": measured.tolist(), "error": err.tolist()}
            for v in VARIANTS:
                row[v] = self.predict(variants[v]["params"], (dy, dx), v)["value"].tolist()
            out["lags"][f"{dy},{dx}"] = row
        return out
