"""The bond map (IPC varying across the detector): the model, its file, the kernel rule.

The reference NumPy coupling with a map is checked against a pixel loop written
here from the module's equation, so the map's indexing is tested independently.
"""

import numpy as np
import pytest

from ipc_taichi.bondmap import BondMap, bonds_from_kernels, interpolate
from ipc_taichi.errors import IPCInputError, LawError
from ipc_taichi.geometry import Geometry
from ipc_taichi.model import CouplingModel
from ipc_taichi.reference import couple_reference, decouple_reference


def _loop_couple(s, alpha, weights, factor, edge):
    """M(p) = S(p) + sum_d b(p, p+d) [w(-d) a(S_q,S_p) S_q - w(d) a(S_p,S_q) S_p], q = p+d,
    with b(p, p+d) from ``factor(p, d)``; outside pixels hold zero signal."""
    ny, nx = s.shape
    out = s.copy()
    for y in range(ny):
        for x in range(nx):
            for (dy, dx), w in weights.items():
                qy, qx = y + dy, x + dx
                inside = 0 <= qy < ny and 0 <= qx < nx
                if not inside and edge == "isolated":
                    continue
                sq = s[qy, qx] if inside else 0.0
                b = factor(y, x, dy, dx)
                out[y, x] -= b * w * alpha(s[y, x], sq) * s[y, x]
                if inside:
                    out[y, x] += b * weights.get((-dy, -dx), 0.0) * alpha(sq, s[y, x]) * sq
    return out


@pytest.mark.parametrize("edge", ["zero", "isolated"])
def test_reference_matches_the_equation_with_a_map(edge):
    rng = np.random.default_rng(3)
    geometry = Geometry({(0, 1): 1.0, (0, -1): 0.8, (1, 0): 1.1, (-1, 0): 1.1, (1, 1): 0.3,
                         (-1, -1): 0.3, (0, 2): 0.1, (0, -2): 0.1})
    shape = (7, 9)
    bonds = BondMap.full(geometry, rng.uniform(0.4, 1.6, (4, *shape)))
    model = CouplingModel.resolve("donlon2018", geometry, edge, bonds=bonds)
    s = rng.uniform(0, 60000, shape)
    stored = {u: k for k, u in enumerate(bonds.offsets)}

    def factor(y, x, dy, dx):
        if (dy, dx) in stored:  # bond stored at its start, edge values replicated
            k, py, px = stored[(dy, dx)], y, x
        else:
            k, py, px = stored[(-dy, -dx)], y + dy, x + dx
        return bonds.values[k, min(max(py, 0), shape[0] - 1), min(max(px, 0), shape[1] - 1)]

    want = _loop_couple(s, model.law.alpha, dict(geometry.weights), factor, edge)
    assert np.allclose(couple_reference(s, model=model), want, rtol=0, atol=1e-8)


def test_map_conserves_charge_and_inverts():
    rng = np.random.default_rng(4)
    g = Geometry.nearest()
    bonds = BondMap.full(g, rng.uniform(0.5, 1.5, (2, 20, 30)))
    model = CouplingModel.resolve("donlon2018", g, "isolated", bonds=bonds)
    s = rng.uniform(0, 50000, (20, 30))
    m = couple_reference(s, model=model)
    assert abs(m.sum() - s.sum()) < 1e-6
    uniform = couple_reference(s, model=model.uniform())
    assert np.abs(m - uniform).max() > 10.0  # the map matters
    d, _, converged, _ = decouple_reference(m, model=model, tol=1e-12, max_iter=100)
    assert converged and np.abs(d - s).max() < 1e-6


def test_map_of_ones_is_the_uniform_model():
    g = Geometry.nearest()
    model = CouplingModel.resolve("donlon2018", g, bonds=BondMap.full(g, np.ones((5, 6))))
    assert model.bonds is None and model == CouplingModel.resolve("donlon2018", g)


def test_map_refusals():
    g = Geometry.nearest()
    with pytest.raises(IPCInputError, match="offsets"):
        BondMap.full(Geometry.terms(diagonal=1.0), np.ones((5, 5))).check(g)
    with pytest.raises(IPCInputError, match="the frame 5x7"):
        BondMap.full(g, np.ones((5, 6))).check(g, (5, 7))
    with pytest.raises(IPCInputError, match="non-negative"):
        BondMap.full(g, -np.ones((5, 6)))
    with pytest.raises(LawError, match="too strong"):
        CouplingModel.resolve("constant:0.1", g, bonds=BondMap.full(g, np.full((4, 4), 1.5)))
    with pytest.raises(IPCInputError, match="not both"):
        CouplingModel.resolve(model=CouplingModel.resolve(), bonds=BondMap.full(g, np.ones((2, 2))))


def test_superpixel_interpolation():
    coarse = np.array([[1.0, 2.0], [3.0, 5.0]])
    full = interpolate(coarse, (4, 4), (8, 8))
    # centres at pixel 1.5 and 5.5: constant beyond them, linear between
    assert full[0, 0] == 1.0 and full[7, 7] == 5.0
    assert full[1, 0] == pytest.approx(1.0 + (3.0 - 1.0) * 0.0)
    assert full[3, 0] == pytest.approx(1.0 + 2.0 * 1.5 / 4)
    assert interpolate(coarse, (4, 4), (8, 8), (0.0, 0.5))[0, 2] == pytest.approx(1.0 + 1.0 / 4)


def test_model_file_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    g = Geometry.nearest()
    sp = BondMap.superpixels(g, rng.uniform(0.8, 1.2, (2, 4, 6)), (5, 5), (20, 30))
    full = BondMap.full(g, rng.uniform(0.8, 1.2, (2, 20, 30)))
    for name, bonds in (("sp.json", sp), ("full.json", full)):
        CouplingModel.resolve("donlon2018", g, bonds=bonds).save(tmp_path / name)
        back = CouplingModel.load(tmp_path / name)
        assert back.bonds == bonds
    assert (tmp_path / "full.bonds.npz").exists() and not (tmp_path / "sp.bonds.npz").exists()
    (tmp_path / "full.bonds.npz").unlink()
    with pytest.raises(IPCInputError, match="full.json.*bond map"):
        CouplingModel.load(tmp_path / "full.json")


@pytest.mark.parametrize("convention", ["scatter", "gather"])
def test_kernels_to_bonds_rule(convention):
    """Kernels made from a known map give it back exactly, and a non-conserving
    kernel's asymmetry is the rule's error."""
    rng = np.random.default_rng(6)
    g = Geometry.nearest()
    ny, nx, a = 12, 15, 0.012
    b = rng.uniform(0.6, 1.4, (2, ny, nx))
    scatter = np.zeros((3, 3, ny, nx))
    scatter[1, 2] = a * b[0]                       # to +x: bond (p, p+x) stored at p
    scatter[1, 0] = a * np.roll(b[0], 1, axis=1)   # to -x: bond stored at p-x
    scatter[2, 1] = a * b[1]
    scatter[0, 1] = a * np.roll(b[1], 1, axis=0)
    scatter[1, 1] = 1 - scatter.sum(axis=(0, 1))
    kernels = scatter
    if convention == "gather":  # G_q(e) = K_{q+e}(-e)
        kernels = np.zeros_like(scatter)
        for j in range(3):
            for i in range(3):
                kernels[j, i] = np.roll(scatter[2 - j, 2 - i], (1 - j, 1 - i), axis=(0, 1))
    bonds, error = bonds_from_kernels(kernels, g, a, convention)
    inner = (slice(1, -1), slice(1, -1))
    assert np.allclose(bonds.values[0][inner], b[0][inner], atol=1e-12)
    assert np.allclose(bonds.values[1][inner], b[1][inner], atol=1e-12)
    assert error[:, 1:-1, 1:-1].max() < 1e-12
    lopsided = scatter.copy()
    lopsided[1, 2] *= 1.1
    _, error = bonds_from_kernels(lopsided, g, a)
    assert np.allclose(error[0][inner], 0.05 * b[0][inner], rtol=1e-9)
