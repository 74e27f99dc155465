"""One brighter-fatter model, two parametrisations (``ipc_taichi.brighterfatter``):
calibrate's kernel ``a`` (pixel area ``1 + sum_d a(d) Q(p+d)``) and discover's
boundary shifts (``effects.brighter_fatter``) converted into each other, and
the same physics when charge is collected with either."""

import numpy as np
import pytest
from scipy.ndimage import convolve, gaussian_filter

from ipc_taichi.brighterfatter import (
    BF_REFERENCE,
    KERNEL_LIMITS,
    deflection_from_kernel,
    isolated_loss,
    kernel_error_from_deflection,
    kernel_from_deflection,
    kernel_plausibility,
)
from ipc_taichi.discover.effects import BF_STEPS, brighter_fatter

PARAMS = ("deflection_x_at_50ke", "deflection_y_at_50ke", "reach", "upwind")


def test_kernel_terms_and_round_trip():
    dx, dy, r = 0.03, 0.05, 0.12
    a = kernel_from_deflection(dx, dy, r)
    cx, cy = dx / (2 * BF_REFERENCE), dy / (2 * BF_REFERENCE)  # upwind 1
    s = cx + cy
    assert a[2, 2] == pytest.approx(-2 * s * (1 - r), rel=1e-12)
    assert a[2, 1] == a[2, 3] == pytest.approx(cx - 2 * r * s, rel=1e-12)
    assert a[1, 2] == a[3, 2] == pytest.approx(cy - 2 * r * s, rel=1e-12)
    assert a[1, 1] == a[3, 3] == pytest.approx(r * s, rel=1e-12)
    assert a[2, 0] == pytest.approx(r * cx, rel=1e-12) and a[0, 2] == pytest.approx(r * cy)
    assert a[0, 1] == a[1, 0] == a[0, 0] == 0.0
    assert abs(a.sum()) < 1e-20  # area is conserved
    for dx, dy, r in ((0.03, 0.05, 0.12), (0.016, 0.016, 0.0), (0.05, 0.01, -0.2)):
        back = deflection_from_kernel(kernel_from_deflection(dx, dy, r))
        assert [back[k] for k in PARAMS] == pytest.approx([dx, dy, r, 1.0], rel=1e-9, abs=1e-12)
        assert back["unrepresented"] < 1e-9 and abs(back["outside_5x5"]) < 1e-18
    # upwind only rescales the strengths: c = d / ((1 + w) Q_ref)
    np.testing.assert_allclose(kernel_from_deflection(0.02, 0.04, 0.1, upwind=0.0),
                               kernel_from_deflection(0.04, 0.08, 0.1, upwind=1.0), rtol=1e-12)
    back = deflection_from_kernel(kernel_from_deflection(0.02, 0.04, 0.1, 0.0), upwind=0.0)
    assert back["deflection_y_at_50ke"] == pytest.approx(0.04, rel=1e-9)


def test_terms_the_boundary_picture_cannot_hold_are_reported():
    # GalSim 2.8's SiliconSensor, measured with the area picture (a charge of
    # 2e5 e- in one pixel, a flat photon-shot over it with the boundaries
    # held; docs/discover.md): nearest terms differ along x and y, the
    # second neighbours are not in the boundary picture's ratio, and 2e-7 of
    # area lies in a tail beyond the 5x5
    galsim = np.array([[0.040, 0.104, 0.144, 0.085, 0.066],
                       [0.089, 0.304, 1.920, 0.308, 0.078],
                       [0.117, 0.822, -10.141, 0.837, 0.120],
                       [0.102, 0.275, 1.885, 0.325, 0.065],
                       [0.057, 0.092, 0.155, 0.092, 0.054]]) * 1e-7
    out = deflection_from_kernel(galsim)
    assert out["outside_5x5"] == pytest.approx(2.01e-7, rel=0.01)
    residual = np.array(out["residual"])
    np.testing.assert_allclose(residual, galsim - kernel_from_deflection(
        *(out[k] for k in PARAMS)), atol=1e-20)
    assert 0.1 < out["unrepresented"] < 0.5
    assert "5x5 sums to" in out["note"] and "(dy, dx) =" in out["note"]
    assert out["deflection_y_at_50ke"] > out["deflection_x_at_50ke"] > 0  # stronger along y
    assert 0 < out["reach"] < 0.2
    # and it is a real detector's kernel
    assert kernel_plausibility(galsim) is None
    # a term added where the picture has none is left in the residual, not dropped
    odd = kernel_from_deflection(0.03, 0.03, 0.1)
    odd[0, 1] += 5e-8
    left = np.array(deflection_from_kernel(odd)["residual"])
    assert left[0, 1] == pytest.approx(5e-8, rel=0.05)


def _kernel_collection(light, kernel, steps=BF_STEPS):
    """Collect ``light`` (e- over the exposure) in ``steps`` slices with pixel areas
    ``1 + sum_d a(d) Q(p + d)`` (midpoint charge), the kernel picture written out."""
    arrive = light / steps
    q = np.zeros_like(light)
    for _ in range(steps):
        qm = q + 0.5 * arrive
        area = 1.0 + convolve(qm, kernel[::-1, ::-1], mode="constant")
        q = q + arrive * area
    return q


@pytest.mark.parametrize("upwind", [0.0, 1.0])
def test_both_pictures_collect_the_same_flat_ish_scene(upwind):
    # light 30 ke- modulated by a smooth pattern of relative amplitude eps: the
    # kernel of the conversion, used as pixel areas, collects what discover's
    # boundary shifts collect, to first order. Why and how close: on a flat
    # field the two are the same (light equal on both sides of every
    # boundary, where calibrate measures the kernel); off it the boundary
    # picture moves the light next to each boundary, the area picture the
    # pixel's own, and they differ by (boundary shift) x (difference of the
    # two pixels' light), a term of order eps^2 beside the brighter-fatter
    # signal's eps: relative to the signal, first order in eps (measured
    # 0.43-0.53 eps for upwind 0 and 1; tolerance 0.6 eps, and halving eps
    # must halve it)
    n = 32
    pattern = gaussian_filter(np.random.default_rng(2).standard_normal((n, n)), 1.5,
                              mode="wrap")
    pattern /= np.abs(pattern).max()
    dx, dy, reach = 0.03, 0.05, 0.1
    kernel = kernel_from_deflection(dx, dy, reach, upwind)
    inner = (slice(3, -3), slice(3, -3))  # the frame edge: nothing beyond it in either
    ratios = []
    for eps in (0.1, 0.05):
        light = 30000.0 * (1.0 + eps * pattern)
        boundary = brighter_fatter(light, dx, dy, upwind, reach)
        signal = np.abs(boundary - light)[inner].max()
        assert signal > 5.0  # e-: well above rounding
        ratios.append(np.abs(_kernel_collection(light, kernel) - boundary)[inner].max() / signal)
        assert ratios[-1] < 0.6 * eps
    assert ratios[0] / ratios[1] == pytest.approx(2.0, rel=0.15)
    flat = np.full((24, 24), 30000.0)  # 6 px from the edge: out of its reach in 8 slices
    np.testing.assert_allclose(_kernel_collection(flat, kernel)[6:-6, 6:-6],
                               brighter_fatter(flat, dx, dy, upwind, reach)[6:-6, 6:-6],
                               rtol=1e-10)


def test_both_pictures_agree_on_a_hot_pixel():
    # a 50 ke- spot uniform in its pixel, empty neighbours, the strict boundary
    # shift (upwind 1): the spot keeps what its kernel area gives it, to second
    # order in the deflection (its neighbours' charge feeds back in later
    # slices); the kernel picture does not say where the lost light goes, the
    # boundary picture gives it to the neighbours, charge conserved
    light = np.zeros((9, 9))
    light[4, 4] = BF_REFERENCE
    dx, dy, reach = 0.02, 0.03, 0.1
    kernel = kernel_from_deflection(dx, dy, reach)
    boundary = brighter_fatter(light, dx, dy, 1.0, reach)
    area = _kernel_collection(light, kernel)
    loss_boundary = BF_REFERENCE - boundary[4, 4]
    loss_area = BF_REFERENCE - area[4, 4]
    loss = isolated_loss(kernel)  # the first-order loss, -a(0,0) Q / 2: 2.25 %
    assert loss == pytest.approx((dx + dy) * (1 - reach) / 2, rel=1e-12)
    # both lose it to first order (the spot's own shrinking charge lowers it by
    # about the loss itself in relative terms), and the same to second order
    assert loss_area == pytest.approx(loss * BF_REFERENCE, rel=2 * loss)
    assert loss_boundary == pytest.approx(loss_area, rel=0.01)
    assert boundary.sum() == pytest.approx(BF_REFERENCE, rel=1e-12)
    # the neighbours' share along y over x: dy / dx, as the kernel's nearest terms say
    assert (boundary[3, 4] / boundary[4, 3]) == pytest.approx(dy / dx, rel=0.05)


def test_kernel_errors_from_the_parameters_covariance():
    params = {"deflection_x_at_50ke": 0.03, "deflection_y_at_50ke": 0.04, "upwind": 0.6,
              "reach": 0.25}
    keys = ("deflection_x_at_50ke", "deflection_y_at_50ke", "upwind", "reach")
    cov = np.diag([0.001, 0.002, 0.05, 0.01]) ** 2
    err = kernel_error_from_deflection(params, cov, keys)
    rng = np.random.default_rng(5)
    draws = []
    for x in rng.multivariate_normal([params[k] for k in keys], cov, 4000):
        p = dict(zip(keys, x))
        draws.append(kernel_from_deflection(p["deflection_x_at_50ke"],
                                            p["deflection_y_at_50ke"], p["reach"], p["upwind"]))
    spread = np.std(draws, axis=0)
    # first order: the spread of 4000 draws (2 % of its value) and 1 / (1 + w)
    # curving over the upwind's 0.05: 5 %
    for term in ((2, 2), (1, 1), (2, 1), (1, 2)):
        assert err[term] == pytest.approx(spread[term], rel=0.05)


def test_physical_range_of_a_kernel():
    # the diffusion-only file's fit on pixel totals (docs/discover.md): reach
    # at its bound, a centre of zero and nearest terms of -2.4e-6
    fake = kernel_from_deflection(0.0787, 0.0799, 1.0)
    why = kernel_plausibility(fake)
    assert why is not None and "strongest at its own pixel" in why
    # an isolated 50 ke- pixel losing 18.7 %: far beyond a real detector
    big = kernel_from_deflection(0.187, 0.187)
    assert "18.7 %" in kernel_plausibility(big)
    assert -big[2, 2] > KERNEL_LIMITS["centre_max"]
    # a pixel's own charge enlarging it
    assert "enlarge" in kernel_plausibility(-kernel_from_deflection(0.02, 0.03))
    # GalSim's sensor as discover fitted it (48x48, upwind 0.77, reach 0.33):
    # the nearest term along x a little negative, the centre dominant: physical
    fitted = kernel_from_deflection(0.0281, 0.0362, 0.3331, 0.7654)
    assert fitted[2, 1] < 0 and kernel_plausibility(fitted) is None
    # the errors decide close calls: a centre just below a neighbour's term
    close = kernel_from_deflection(0.03, 0.03, 0.7)
    assert kernel_plausibility(close) is not None
    assert kernel_plausibility(close, np.full((5, 5), 1e-7)) is None
    assert kernel_plausibility(close, np.full((5, 5), 1e-8)) is not None
