"""Brighter-fatter: one physical model, two parametrisations.

Charge already collected during an exposure repels the charge still
arriving: the pixel boundaries move, a full pixel collects from a smaller
area and its neighbours from larger ones. The project writes this once as a
*kernel* and once as *boundary shifts*, and this module is the one place
where the two are converted into each other.

The kernel (``ipc-taichi calibrate``; Antilogus et al. 2014, Hirata & Choi 2020)
    The area of pixel ``p``, in units of a nominal pixel, is
    ``A_p = 1 + sum_d a(d) Q(p + d)``: a 5x5 array ``a[2 + dy][2 + dx]`` per
    electron of collected charge ``Q``, ``sum a = 0`` (area is conserved),
    ``a[2][2] < 0`` (a pixel's own charge shrinks it), the other terms
    positive for a repelling charge.

The boundary shifts (``ipc-taichi discover``, :func:`ipc_taichi.discover.effects.brighter_fatter`)
    The boundary between neighbours ``p`` and ``q = p + e`` (``e`` one step
    along x or y) moves into the fuller pixel by the fraction of a pixel
    width ``s_pq = c_e (Phi_p - Phi_q)``, where ``Phi = Q + r N[Q]`` is the
    charge plus ``reach`` (``r``) times the charge of the 4 nearest
    neighbours (``N``), and the strip the boundary sweeps hands its
    arrivals to the other pixel. The strengths are quoted as
    ``deflection_x_at_50ke`` and ``deflection_y_at_50ke`` (``d_x, d_y``):
    ``c_e = d_e / ((1 + w) Q_ref)`` with ``Q_ref`` = :data:`BF_REFERENCE`
    and ``w`` = ``upwind``, so that a pixel holding ``Q_ref`` among empty
    neighbours sends ``d_e`` of its arrivals across its two boundaries
    along ``e`` (for ``r = 0``).

Derivation (first order in the charge)
--------------------------------------
Let light arrive uniformly over a pixel and its neighbours (``f`` per unit
area). In one slice of the exposure the charge pixel ``p`` gains is ``f``
times its area; each of its four boundaries, moved by ``s_pq`` into ``p``,
takes the strip ``s_pq`` from it, whichever pixel's light the strip is
said to carry (``upwind`` does not matter when the light is the same on
both sides). So::

    A_p = 1 - sum_e c_e (2 Phi_p - Phi_{p+e} - Phi_{p-e})
        = 1 - (L * (delta + r N) * Q)_p

with ``L = sum_e c_e (2 delta - delta_{+e} - delta_{-e})`` the discrete
(anisotropic) Laplacian and ``*`` a convolution. Hence
``a = -L * (delta + r N)``; written out, with ``S = c_x + c_y``:

================  ==================  ======================================
term              offset              ``a``
================  ==================  ======================================
centre            (0, 0)              ``-2 S (1 - r)``
nearest along x   (0, +-1)            ``c_x - 2 r S``
nearest along y   (+-1, 0)            ``c_y - 2 r S``
diagonal          (+-1, +-1)          ``r S``
second along x    (0, +-2)            ``r c_x``
second along y    (+-2, 0)            ``r c_y``
================  ==================  ======================================

The terms sum to zero for every ``c_x, c_y, r``. ``reach`` is the only
way the boundary picture puts area into the diagonal and second
neighbours, always in the ratio ``S : c_x : c_y``, and it takes twice the
diagonal from each nearest neighbour: a charge that pushes its neighbours'
far boundaries also shrinks them. The terms the boundary picture cannot
hold are the rest of a measured kernel: the offsets ``(+-1, +-2)``,
``(+-2, +-1)`` and ``(+-2, +-2)``, a diagonal or second-neighbour part out
of that ratio, a difference between ``+d`` and ``-d``, and a 5x5 sum that is
not zero (a tail beyond the 5x5). :func:`deflection_from_kernel` reports
them (``residual``, ``outside_5x5``) instead of dropping them.

Where the two pictures differ
-----------------------------
They are the same for light that is smooth across neighbouring pixels
(flat fields, broad sources), for every ``upwind``. Where the light
changes from one pixel to the next (a hot pixel, a patch edge, a star's
core), the kernel alone does not say whose light a moved boundary hands
over; read as "area times the pixel's own light" it is the strict
boundary shift (``upwind = 1``), exact for light uniform within each pixel.
A discover fit with ``upwind = w < 1`` hands over part of the neighbour's
light (``w = 0``: the flow of the difference of squared charges, the
continuity-equation form of Coulton et al. 2018); its kernel is the
response to smooth light, ``c_e = d_e / ((1 + w) Q_ref)``.

What real detectors show
------------------------
An isolated pixel of ``Q`` electrons loses ``-a(0,0) Q / 2`` of its charge
over the exposure (the mean charge during it is ``Q / 2``). Measured:

- Roman's H4RG-10 HgCdTe arrays: a pixel's area grows by about
  ``3.5e-7`` per electron in a nearest neighbour (Freudenburg et al. 2020,
  PASP 132, 074504).
- GalSim 2.8's ``SiliconSensor`` (the electrostatic model of an LSST ITL
  thick CCD, Lage et al. 2017), measured with the area picture itself (a
  charge of ``2e5`` e- in one pixel, a flat photon-shot over it with the
  boundaries held): ``a(0,0) = -1.01e-6``, nearest ``0.83e-7`` (x) and
  ``1.9e-7`` (y), diagonal ``0.31e-7``, second ``0.12e-7`` / ``0.15e-7``,
  and ``2e-7`` in a tail beyond the 5x5; a 50 ke- top-hat spot shot
  through it loses 2.6 % of its charge.
- Thick CCDs: stars grow by up to 2 % of their size over the full dynamic
  range (Antilogus et al. 2014).

:func:`kernel_plausibility` calls a kernel physical when a pixel's own
charge shrinks it, changes its area more than any other pixel's does, and
the centre term is at most :data:`KERNEL_LIMITS` ``centre_max`` = ``4e-6``
per electron in size: about twice the H4RG-10's (its centre is at least 4
times its nearest term, the kernel summing to zero) and four times the
thick CCD's. For the strict boundary picture without reach that is a mean
deflection of 10 % at 50 ke-, the limit discover used before it judged the
kernel.
"""

import math

import numpy as np

__all__ = ["BF_REFERENCE", "KERNEL_SIZE", "KERNEL_LIMITS", "boundary_strengths",
           "kernel_from_deflection", "kernel_error_from_deflection", "deflection_from_kernel",
           "kernel_plausibility", "isolated_loss"]

BF_REFERENCE = 50000.0  # e-: the charge at which discover quotes its deflections
KERNEL_SIZE = 5  # the kernel is KERNEL_SIZE x KERNEL_SIZE, indexed [2 + dy][2 + dx]
_C = KERNEL_SIZE // 2

# The physical range of a brighter-fatter kernel (per electron; module docstring)
KERNEL_LIMITS = {"centre_max": 4.0e-6}


def boundary_strengths(deflection_x_at_50ke, deflection_y_at_50ke, upwind=1.0):
    """``(c_x, c_y)``: the boundary shift per electron of charge difference,
    in pixel widths, ``c_e = d_e / ((1 + upwind) Q_ref)``."""
    scale = 1.0 / ((1.0 + float(upwind)) * BF_REFERENCE)
    return float(deflection_x_at_50ke) * scale, float(deflection_y_at_50ke) * scale


def _kernel(cx, cy, r):
    """The 5x5 kernel of boundary strengths ``c_x, c_y`` and reach ``r`` (table above)."""
    s = cx + cy
    a = np.zeros((KERNEL_SIZE, KERNEL_SIZE))
    a[_C, _C] = -2.0 * s * (1.0 - r)
    a[_C, _C - 1] = a[_C, _C + 1] = cx - 2.0 * r * s
    a[_C - 1, _C] = a[_C + 1, _C] = cy - 2.0 * r * s
    for dy in (-1, 1):
        for dx in (-1, 1):
            a[_C + dy, _C + dx] = r * s
    a[_C, _C - 2] = a[_C, _C + 2] = r * cx
    a[_C - 2, _C] = a[_C + 2, _C] = r * cy
    return a


def kernel_from_deflection(deflection_x_at_50ke, deflection_y_at_50ke, reach=0.0, upwind=1.0):
    """The kernel ``a`` (5x5, per electron, ``a[2 + dy][2 + dx]``) of discover's
    boundary-shift parameters.

    Parameters
    ----------
    deflection_x_at_50ke, deflection_y_at_50ke : float
        Discover's ``brighter_fatter`` strengths (fractions at 50 ke-).
    reach : float
        How much the 4 nearest neighbours' charge adds to the field that
        moves a boundary.
    upwind : float
        Whose light a moved boundary hands over (1: the shrinking pixel's,
        the strict boundary shift; 0: the two pixels' mean). The kernel is
        the response to light smooth across neighbours, where the two
        agree: ``c_e = d_e / ((1 + upwind) Q_ref)``.

    Returns
    -------
    numpy.ndarray
        ``a`` with ``A_p = 1 + sum_d a(d) Q(p + d)``; its terms are those of
        the table in the module docstring and sum to zero.
    """
    cx, cy = boundary_strengths(deflection_x_at_50ke, deflection_y_at_50ke, upwind)
    return _kernel(cx, cy, float(reach))


def kernel_error_from_deflection(params, cov, keys=("deflection_x_at_50ke",
                                                    "deflection_y_at_50ke", "upwind", "reach")):
    """One-sigma errors of :func:`kernel_from_deflection` at ``params``, propagated
    from the covariance ``cov`` of the parameters ``keys`` (in that order) to
    first order (numerical derivatives)."""
    x = np.array([float(params[k]) for k in keys])
    cov = np.asarray(cov, dtype=np.float64)

    def kern(v):
        p = dict(zip(keys, v))
        return kernel_from_deflection(p["deflection_x_at_50ke"], p["deflection_y_at_50ke"],
                                      p["reach"], p["upwind"]).ravel()

    jac = []
    for i in range(len(x)):
        h = 1e-6 * max(abs(x[i]), 1e-3)
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        jac.append((kern(up) - kern(down)) / (2 * h))
    jac = np.array(jac).T  # (25, k)
    var = np.einsum("ij,jk,ik->i", jac, cov, jac)
    return np.sqrt(np.clip(var, 0.0, None)).reshape(KERNEL_SIZE, KERNEL_SIZE)


def _design():
    """Columns of the kernel, linear in ``(c_x, c_y, r c_x, r c_y)``."""
    cols = []
    for cx, cy, px, py in np.eye(4):
        a = np.zeros((KERNEL_SIZE, KERNEL_SIZE))
        a[_C, _C] = -2.0 * (cx + cy) + 2.0 * (px + py)
        a[_C, _C - 1] = a[_C, _C + 1] = cx - 2.0 * (px + py)
        a[_C - 1, _C] = a[_C + 1, _C] = cy - 2.0 * (px + py)
        for dy in (-1, 1):
            for dx in (-1, 1):
                a[_C + dy, _C + dx] = px + py
        a[_C, _C - 2] = a[_C, _C + 2] = px
        a[_C - 2, _C] = a[_C + 2, _C] = py
        cols.append(a.ravel())
    return np.column_stack(cols)


def deflection_from_kernel(kernel, kernel_error=None, upwind=1.0):
    """Discover's boundary-shift parameters closest to a kernel, and what they
    cannot hold.

    The kernel of :func:`kernel_from_deflection` is linear in
    ``(c_x, c_y, r c_x, r c_y)``; those four are fitted by (weighted) least
    squares to the 25 terms, ``r`` is their ratio, and ``c_x, c_y`` are
    refitted with ``r`` held (the boundary picture ties the two ratios).

    Parameters
    ----------
    kernel : array_like
        5x5, per electron, ``a[2 + dy][2 + dx]`` (module docstring).
    kernel_error : array_like, optional
        5x5 one-sigma errors: terms weighted by ``1 / error^2`` (zero or
        missing errors: equal weights).
    upwind : float
        The ``upwind`` of the result (1, the strict boundary shift, is the
        picture the kernel's "area times the pixel's light" describes).

    Returns
    -------
    dict
        ``deflection_x_at_50ke``, ``deflection_y_at_50ke``, ``reach``,
        ``upwind`` (discover's parameters); ``residual``, the kernel minus
        the kernel of those parameters (5x5 list: what the boundary picture
        cannot hold); ``outside_5x5``, minus the kernel's sum (area that a
        tail beyond the 5x5 would have to return); ``unrepresented``, the
        share ``sum |residual| / sum |kernel|``; ``note``, a sentence naming
        the largest term left out.
    """
    a = np.asarray(kernel, dtype=np.float64)
    if a.shape != (KERNEL_SIZE, KERNEL_SIZE) or not np.all(np.isfinite(a)):
        raise ValueError(f"a brighter-fatter kernel is a finite {KERNEL_SIZE}x{KERNEL_SIZE} "
                         f"array, got shape {a.shape}")
    weight = np.ones(a.size)
    if kernel_error is not None:
        err = np.asarray(kernel_error, dtype=np.float64).ravel()
        good = np.isfinite(err) & (err > 0)
        if good.all():
            weight = 1.0 / err
    design = _design() * weight[:, None]
    target = a.ravel() * weight
    cx, cy, px, py = np.linalg.lstsq(design, target, rcond=None)[0]
    r = (px + py) / (cx + cy) if cx + cy != 0 else 0.0
    # c_x, c_y with r held: the kernel is linear in them then
    basis = np.column_stack([_kernel(1.0, 0.0, r).ravel(), _kernel(0.0, 1.0, r).ravel()])
    cx, cy = np.linalg.lstsq(basis * weight[:, None], target, rcond=None)[0]
    scale = (1.0 + float(upwind)) * BF_REFERENCE
    model = _kernel(cx, cy, r)
    residual = a - model
    total = float(np.abs(a).sum())
    out = {"deflection_x_at_50ke": float(cx * scale), "deflection_y_at_50ke": float(cy * scale),
           "reach": float(r), "upwind": float(upwind), "residual": residual.tolist(),
           "outside_5x5": float(-a.sum()),
           "unrepresented": float(np.abs(residual).sum() / total) if total > 0 else 0.0}
    out["note"] = _residual_note(residual, out["outside_5x5"], total)
    return out


def _residual_note(residual, outside, total):
    """One sentence on the largest kernel term the boundary picture leaves out."""
    iy, ix = np.unravel_index(int(np.argmax(np.abs(residual))), residual.shape)
    worst = float(residual[iy, ix])
    parts = [f"the boundary picture leaves {100 * np.abs(residual).sum() / total:.0f} % of the "
             f"kernel's terms (sum of magnitudes) out" if total > 0 else "an empty kernel"]
    if total > 0 and worst != 0.0:
        parts.append(f"the largest at offset (dy, dx) = ({iy - _C}, {ix - _C}): {worst:+.3g} "
                     "per electron")
    if total > 0 and abs(outside) > 0.01 * total:
        parts.append(f"the 5x5 sums to {-outside:+.3g} per electron, which a tail beyond it "
                     "must return (the boundary picture's kernel sums to zero)")
    return "; ".join(parts)


def isolated_loss(kernel, charge=BF_REFERENCE):
    """The fraction of its charge an isolated pixel of ``charge`` electrons
    (among empty neighbours, light uniform within it) loses over the
    exposure: ``-a(0, 0) charge / 2``."""
    return -float(np.asarray(kernel)[_C, _C]) * float(charge) / 2.0


def kernel_plausibility(kernel, kernel_error=None, sigmas=3.0):
    """Why a brighter-fatter kernel lies outside what real detectors show, or ``None``.

    Three conditions, each a property of every measured kernel (module
    docstring):

    - a pixel's own charge shrinks it: ``a(0,0) < 0``;
    - it changes its own pixel's area more than any other pixel's:
      ``-a(0,0) >= |a(d)|`` for every ``d != 0`` (the field of a collected
      charge is strongest at its own pixel's boundaries; about 4 times the
      nearest term on an H4RG-10, 10 times on GalSim's thick CCD);
    - its size is within :data:`KERNEL_LIMITS`: ``-a(0,0)`` at most
      ``centre_max`` per electron.

    With ``kernel_error`` (5x5 one-sigma errors) the first two fail only by
    more than ``sigmas`` errors; the size limit applies to the value. The
    signs of the other terms are not required: a boundary-shift fit
    (:func:`kernel_from_deflection`) that stands in for a field reaching
    beyond its 5x5 trades nearest terms for ``reach`` (on GalSim's sensor its
    nearest term along x came out ``-1.0e-7 +- 0.2e-7`` beside a centre of
    ``-1.2e-6``, the sensor's own being ``+0.8e-7`` and ``-1.0e-6``).
    """
    a = np.asarray(kernel, dtype=np.float64)
    e = np.zeros_like(a) if kernel_error is None else np.nan_to_num(
        np.asarray(kernel_error, dtype=np.float64))
    k = float(sigmas)
    centre, ecentre = a[_C, _C], e[_C, _C]
    if centre > k * ecentre:
        return (f"a pixel's own charge would enlarge it (centre term {centre:+.3g} per "
                "electron; a repelling charge shrinks its pixel)")
    others = np.abs(a).copy()
    others[_C, _C] = -np.inf
    iy, ix = np.unravel_index(int(np.argmax(others)), a.shape)
    if abs(a[iy, ix]) + centre > k * math.hypot(e[iy, ix], ecentre):
        return (f"a charge would change the area of the pixel at (dy, dx) = ({iy - _C}, "
                f"{ix - _C}) by {a[iy, ix]:+.3g} per electron, more than its own pixel's "
                f"({centre:+.3g}): the field of a collected charge is strongest at its own "
                "pixel")
    if -centre > KERNEL_LIMITS["centre_max"]:
        return (f"a centre term of {centre:.3g} per electron (an isolated 50 ke- pixel would "
                f"lose {100 * isolated_loss(a):.1f} % of its charge over the exposure; real "
                f"detectors: about 1e-6 to 2e-6, at most {KERNEL_LIMITS['centre_max']:g} is "
                "plausible)")
    return None
