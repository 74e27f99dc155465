"""IPC as laboratories measure it: flat-field autocorrelation and hot pixels.

Two classic measurements of the coupling alpha, simulated through the
project's detector chain (:func:`ipc_taichi.detector.expose`: Poisson draw,
coupling, read noise) so that what each would report can be compared with
the law that made the data.

**Flat-field autocorrelation** (Moore et al.). In a flat of level ``S`` the
collected charge is ``S_p = S + n_p`` with independent shot noise of
variance ``V = S`` (gain 1). Coupling mixes the noise of neighbours, so the
measured frame's noise is correlated. Linearise the coupling around the flat:
the charge a neighbour ``q`` gets from pixel ``p`` is
``alpha(S_p, S_q) S_p``, and it gives ``alpha(S_q, S_p) S_q`` back, so

    dM_q / dS_p = alpha(S, S) + S [d1 alpha(S, S) - d2 alpha(S, S)]
                = alpha_lin(S)

(``d1``, ``d2`` the derivatives in the law's first and second argument).
With ``a = alpha_lin(S)`` the measured noise is the shot noise convolved with
the constant kernel ``[a, 1 - 4a, a]`` (4 nearest neighbours), whose
nearest-neighbour covariance and variance are

    C(1, 0) = 2 a (1 - 4 a) V,    C(0, 0) = ((1 - 4 a)^2 + 4 a^2) V + sigma_read^2,

so ``C(1,0) ~ 2 a C(0,0)`` to O(a): for a constant law, the covariance is
about twice alpha times the variance. :func:`alpha_from_flat` solves the
covariances exactly for the kernel (the read noise known from darks), so no
gain is needed; the measurement itself is that of ``ipc-taichi calibrate``
(:mod:`ipc_taichi.calibrate.flats`: masks, NaN, per-axis terms with errors),
and so is the hot-pixel one (:mod:`ipc_taichi.calibrate.hotpixels`).

For the symmetric laws of this project (``alpha(S, N) = alpha(N, S)``, which
charge conservation needs) ``d1 alpha = d2 alpha`` on the diagonal and the
bracket vanishes: a flat measures ``alpha(S, S)`` exactly to first order,
the diagonal of the law. It never sees ``alpha(S, N)`` away from ``N = S``,
which is why the paper says autocorrelation methods cannot explore the
signal dependence. (The "alpha plus the slope times S" form is what a law
that depends on the *source* pixel only, ``a(S_p)``, gives:
``d/dS [a(S) S] = a + S a'``. :func:`couple_source_law` simulates such a
law, so the two predictions can be checked against each other.)

**Hot pixels** (single-pixel events). A hot pixel of ``S`` on a dark
background ``B`` gives each neighbour ``alpha(S, B) S`` and gets back
``alpha(B, S) B``: the ratio of the neighbours' excess to the event's total
charge measures ``alpha(S, B)``, a row of the law far from its diagonal.

Synthetic inputs come from :mod:`ipc_taichi.datasets` (``flat``,
``hot_pixels``).
"""

import numpy as np

__all__ = ["autocovariance", "alpha_from_flat", "flat_covariance_prediction",
           "linearised_alpha", "couple_source_law", "hot_pixel_alpha", "measure_flats",
           "measure_hot_pixels"]

_LAGS = 2  # autocovariance lags kept each way; the 4-neighbour kernel reaches 2 (its square)


def autocovariance(frames, lags=_LAGS):
    """Autocovariance ``C(dy, dx)`` of one frame or a stack, ``|dy|, |dx| <= lags``.

    Each frame's own mean is subtracted; the products are averaged over all
    pixel pairs at that lag inside the frame and over the stack.

    Returns
    -------
    ndarray, shape (2 lags + 1, 2 lags + 1)
        ``C[lags + dy, lags + dx]``.
    """
    stack = np.asarray(frames, dtype=np.float64)
    if stack.ndim == 2:
        stack = stack[None]
    out = np.zeros((2 * lags + 1, 2 * lags + 1))
    for frame in stack:
        d = frame - frame.mean()
        ny, nx = d.shape
        for dy in range(-lags, lags + 1):
            for dx in range(-lags, lags + 1):
                a = d[max(dy, 0):ny + min(dy, 0), max(dx, 0):nx + min(dx, 0)]
                b = d[max(-dy, 0):ny + min(-dy, 0), max(-dx, 0):nx + min(-dx, 0)]
                out[lags + dy, lags + dx] += float(np.mean(a * b))
    return out / len(stack)


def alpha_from_flat(frames, read_noise=0.0, border=2, lags=_LAGS, mask=None,
                    cancel_pattern=None):
    """alpha from the noise covariances of flat fields, per axis, with errors.

    The measurement is :mod:`ipc_taichi.calibrate.flats` (the one
    implementation): covariances at lags (0,0), (0,1), (1,0), (1,1), (0,2),
    (2,0) with masks and NaN left out, solved exactly for ``V`` and the five
    terms of a symmetric 5x5 kernel (``C(l) = V sum_j K[j] K[j+l]``, read
    noise at lag 0), so no gain is needed and no small-alpha approximation is
    made.

    Parameters
    ----------
    frames : ndarray, (ny, nx) or (n, ny, nx)
        Flat fields at one level, as measured.
    read_noise : float
        RMS of the (uncoupled) read noise [e-], known from dark frames; it
        adds to the variance only.
    border : int
        Pixels dropped at each frame edge: with the zero edge, the outermost
        pixels lose charge off the frame, a step that would add to the
        covariance (laboratories likewise leave the border out).
    lags : int
        Kept for compatibility (the lags are those of the 5x5 kernel).
    mask : ndarray of bool, optional
        Pixels not to use (NaN pixels are left out too).
    cancel_pattern : bool or None
        Difference the frames to cancel a fixed pattern (default: when there
        are >= 2 frames); one frame is only mean-subtracted.

    Returns
    -------
    dict
        ``alpha`` (mean of ``alpha_x`` and ``alpha_y`` weighted by their
        errors), ``alpha_x``, ``alpha_y`` (the kernel's horizontal and
        vertical terms; a negative value is reported as measured, not NaN),
        their errors ``alpha_err``, ``alpha_x_err``, ``alpha_y_err``,
        ``terms`` (all five, with errors), ``cov_nn`` (mean of the
        nearest-neighbour covariances), ``var`` (``C(0,0)``), ``ratio``
        ``= cov_nn / var`` and ``V`` (the shot-noise variance).
    """
    from ipc_taichi.calibrate.flats import flat_covariances, solve_kernel

    stack = np.asarray(frames, dtype=np.float64)
    if stack.ndim == 2:
        stack = stack[None]
    if cancel_pattern is None:
        cancel_pattern = stack.shape[0] >= 2
    cov = flat_covariances(stack, mask, border, cancel_pattern=cancel_pattern)
    solved = solve_kernel(cov, read_noise)
    t = solved["terms"]
    ax, ex = t["x"]["value"], t["x"]["error"]
    ay, ey = t["y"]["value"], t["y"]["error"]
    wx, wy = 1.0 / ex ** 2, 1.0 / ey ** 2
    alpha = (wx * ax + wy * ay) / (wx + wy)
    cx = cov["0,1"]["cov"]
    cy = cov["1,0"]["cov"]
    cov_nn = 0.5 * (cx + cy)
    var = cov["0,0"]["cov"]
    return {"alpha": float(alpha), "alpha_err": float(1.0 / np.sqrt(wx + wy)),
            "alpha_x": ax, "alpha_y": ay, "alpha_x_err": ex, "alpha_y_err": ey,
            "terms": t, "cov_nn": cov_nn, "var": var, "ratio": cov_nn / var, "V": solved["V"]}


def flat_covariance_prediction(alpha, V, read_noise=0.0):
    """Nearest-neighbour covariance and variance of a flat coupled by the constant kernel ``alpha``.

    Returns ``(cov_nn, var)``: ``2 a (1 - 4a) V`` and ``((1 - 4a)^2 + 4a^2) V + read_noise^2``.
    """
    a = np.asarray(alpha, dtype=np.float64)
    return 2 * a * (1 - 4 * a) * V, ((1 - 4 * a) ** 2 + 4 * a ** 2) * V + float(read_noise) ** 2


def linearised_alpha(level, law="donlon2018", coupler=None, step=None):
    """``dM_q / dS_p`` on a flat of ``level`` e-: the alpha a flat's noise sees.

    Computed numerically through the coupler itself (a central difference of
    a one-pixel perturbation on a 7x7 flat, no edge effects at its centre), so
    it holds for any law, tabulated ones included.

    Parameters
    ----------
    level : float or array_like
    law : str or law object
        For :func:`ipc_taichi.couple` (``coupler`` None).
    coupler : callable, optional
        ``coupler(frame) -> coupled frame``, e.g. a :func:`couple_source_law`
        partial; overrides ``law``.
    step : float, optional
        Perturbation [e-] (default 0.01: the |S - N| term of a law has a kink on
        the diagonal, so the difference is exact only to O(step / scale)).

    Returns
    -------
    ndarray
        One value per level.
    """
    import ipc_taichi

    if coupler is None:
        def coupler(frame):
            return ipc_taichi.couple(frame, law=law, edge="isolated")
    out = []
    for s in np.atleast_1d(np.asarray(level, dtype=np.float64)):
        h = 0.01 if step is None else float(step)
        diff = 0.0
        for sign in (1.0, -1.0):
            frame = np.full((7, 7), s)
            frame[3, 3] += sign * h
            diff += sign * float(np.asarray(coupler(frame))[3, 4])
        out.append(diff / (2 * h))
    return np.array(out)


def couple_source_law(signal, a_of_s):
    """Couple with a law that depends on the *source* pixel only (NumPy, 4 neighbours).

    Each pixel sends ``a(S_p) S_p`` to each of its 4 nearest neighbours
    (periodic frame: a flat has no edge). Charge is conserved. This is not a
    law of :mod:`ipc_taichi.laws` (those are pair-symmetric): it exists to
    show what a flat measures when the coupling depends on the sender alone.

    Parameters
    ----------
    signal : ndarray, 2-D
    a_of_s : callable
        Vectorised ``a(S)`` (a fraction).
    """
    s = np.asarray(signal, dtype=np.float64)
    sent = a_of_s(s) * s
    received = sum(np.roll(sent, shift, axis) for shift in (1, -1) for axis in (0, 1))
    return s - 4 * sent + received


def hot_pixel_alpha(measured, positions, background=0.0):
    """alpha of single-pixel events: mean neighbour excess over the event's total charge.

    The measurement is :func:`ipc_taichi.calibrate.hotpixels.measure_events`
    (the one implementation): the fraction of each offset of the 5x5 box, the
    total over the box (which holds every coupled neighbour, so the fraction
    is exactly ``w alpha(S, B)`` in the one-step model).

    Parameters
    ----------
    measured : ndarray
        The coupled frame (with noise).
    positions : ndarray of int, shape (k, 2)
        ``(y, x)`` of each hot pixel (isolated, at least 3 pixels from the edge).
    background : float or None
        The dark level [e-] subtracted from each pixel of the box (known from
        the dark frames); None: the median of each event's ring at distance 3.

    Returns
    -------
    alpha : ndarray, shape (k,)
        ``mean(4 neighbours - B) / sum(5x5 box - B)`` for each event (NaN
        where the box holds NaN or leaves the frame).
    total : ndarray, shape (k,)
        The event's total charge in its box [e-].
    """
    from ipc_taichi.calibrate.hotpixels import measure_events

    positions = np.asarray(positions, dtype=int).reshape(-1, 2)
    ev = measure_events(np.asarray(measured, dtype=np.float64), positions,
                        background=background)
    alpha = np.full(len(positions), np.nan)
    total = np.full(len(positions), np.nan)
    frac = ev["fraction"].reshape(-1, 5, 5)
    alpha[ev["event"]] = (frac[:, 1, 2] + frac[:, 3, 2] + frac[:, 2, 1] + frac[:, 2, 3]) / 4.0
    total[ev["event"]] = ev["signal"]
    return alpha, total


def measure_flats(levels, law="donlon2018", size=512, n_frames=2, read_noise=10.0, seed=0,
                  coupler=None):
    """Flat fields at each level through the detector chain, and what their autocorrelation says.

    Parameters
    ----------
    levels : sequence of float
        Flat levels [e-].
    law : str
        Coupling law (``coupler`` None).
    size, n_frames : int
        Frame side and frames per level.
    read_noise : float
        RMS read noise [e-] (added after coupling, known to the measurement).
    seed : int
    coupler : callable, optional
        Replaces the project's coupling (e.g. a :func:`couple_source_law`
        partial); the Poisson draw and the read noise are the chain's.

    Returns
    -------
    list of dict
        Per level: the :func:`alpha_from_flat` values (with ``alpha_err``,
        the standard error from the scatter of the covariance products) plus
        ``level``, ``alpha_lin`` (:func:`linearised_alpha`) and ``alpha_diag``
        (``alpha(S, S)``, for the project's laws).
    """
    from ipc_taichi.datasets import flat
    from ipc_taichi.detector import collect, expose
    from ipc_taichi.detector import read_noise as draw_read_noise
    from ipc_taichi.laws import get_law

    rng = np.random.default_rng(seed)
    rows = []
    for level in levels:
        frames = []
        for _ in range(int(n_frames)):
            expected = flat((size, size), level)
            if coupler is None:
                frames.append(expose(expected, law, read_noise, rng).measured)
            else:
                signal = collect(expected, rng)
                frames.append(coupler(signal) + draw_read_noise(signal.shape, read_noise, rng))
        frames = np.array(frames)
        # simulated flats have no fixed pattern: each frame is only mean-subtracted, so
        # every frame's noise counts (real flats are differenced: calibrate.flats)
        row = alpha_from_flat(frames, read_noise, cancel_pattern=False)
        row["level"] = float(level)
        row["alpha_lin"] = float(linearised_alpha(level, law, coupler)[0])
        row["alpha_diag"] = (float(get_law(law).alpha(level, level)) if coupler is None
                             else float("nan"))
        rows.append(row)
    return rows


def measure_hot_pixels(levels, law="donlon2018", background=0.0, read_noise=10.0, size=256,
                       n_per_frame=200, seed=0):
    """Hot pixels of each level on a dark background through the detector chain.

    Returns
    -------
    list of dict
        Per level: ``level``, ``alpha`` (mean of :func:`hot_pixel_alpha`),
        ``alpha_err`` (its standard error), ``n`` (events), ``alpha_law``
        (``alpha(S, B)`` of the law at the event's level and the background).
    """
    from ipc_taichi.datasets import hot_pixels
    from ipc_taichi.detector import expose
    from ipc_taichi.laws import get_law

    rng = np.random.default_rng(seed)
    rows = []
    for k, level in enumerate(levels):
        expected, positions = hot_pixels((size, size), n_per_frame, level, background=background,
                                         seed=seed + k, isolation=5)
        measured = expose(expected, law, read_noise, rng).measured
        alpha, _ = hot_pixel_alpha(measured, positions, background)
        alpha = alpha[np.isfinite(alpha)]
        rows.append({"level": float(level), "alpha": float(alpha.mean()),
                     "alpha_err": float(alpha.std(ddof=1) / np.sqrt(alpha.size)),
                     "n": int(alpha.size),
                     "alpha_law": float(get_law(law).alpha(level, background))})
    return rows
