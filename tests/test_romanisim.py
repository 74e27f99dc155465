"""The romanisim adapter (ipc_taichi.romanisim): romanisim's own ramps, read by read,
against ``couple`` of the same charge, and a flat's neighbour covariance."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi.model import CouplingModel
from tests.helpers import optional

pytest.importorskip("romanisim", reason=optional("romanisim"))
galsim = pytest.importorskip("galsim", reason=optional("galsim"))
from romanisim import l1  # noqa: E402

from ipc_taichi import romanisim as ours  # noqa: E402

SEED = 7
READS = [[1], [2], [3], [4], [5], [6]]  # each read its own resultant
GROUPED = [[1], [2, 3], [4, 5, 6]]  # the same reads averaged in threes


class _Unchanged:
    """An ipc_model that leaves romanisim's resultants alone (None is its kernel)."""

    def apply(self, img, **kwargs):
        return None


@pytest.fixture
def scene():
    """Counts (electrons by the last read): a sky with two stars."""
    counts = np.random.default_rng(3).poisson(3000.0, (24, 28)).astype(float)
    counts[8, 9], counts[15, 20] = 60000.0, 150000.0
    return counts


@pytest.fixture
def model_file(tmp_path):
    path = tmp_path / "sca01_ipc.json"
    CouplingModel.resolve("donlon2018").save(path)
    return str(path)


LEVELS = dict(pedestal=10000.0, pedestal_extra_noise=8.0, seed=SEED, reference_read=True)


def _uncoupled(scene):
    """Each read's charge and the reset level, from romanisim's own runs (same seed)."""
    one_by_one = l1.read_pattern_to_tij(READS)
    # no pedestal: each read is its accumulated charge exactly (integers in float32)
    charge, _ = l1.apportion_counts_to_resultants(scene, one_by_one, seed=SEED)
    assert np.all(np.diff(charge, axis=0) >= 0) and np.array_equal(charge[-1], scene)
    stock, _ = l1.apportion_counts_to_resultants(scene, one_by_one, **LEVELS)
    assert stock[0].std() > 4.0  # the pedestal noise is there
    return charge.astype(np.float64), stock[0]


def _mean_of_reads(each):
    """The resultants of GROUPED from a stack of reads (READS)."""
    ends = np.cumsum([len(reads) for reads in GROUPED])
    return [each[end - len(reads):end].mean(axis=0) for end, reads in zip(ends, GROUPED)]


def test_every_resultant_is_couple_of_each_reads_charge(scene, model_file, cpu):
    """Read charges and reset level from romanisim's own un-coupled runs (same seed);
    every resultant of the coupled run is the mean over its reads of
    reset + couple(charge), and the reference read is the reset level bit for bit."""
    charge, stock_reset = _uncoupled(scene)
    reset = stock_reset.astype(np.float64)
    coupled, _ = ours.apportion_counts_to_resultants(
        scene, l1.read_pattern_to_tij(GROUPED), model=model_file, **LEVELS)
    assert coupled.shape == (1 + len(GROUPED),) + scene.shape
    np.testing.assert_array_equal(coupled[0], stock_reset)
    each = reset + ipc_taichi.couple(charge, model=model_file)
    for k, (expect, mean_charge) in enumerate(zip(_mean_of_reads(each), _mean_of_reads(charge))):
        np.testing.assert_allclose(coupled[k + 1], expect, rtol=1e-6, atol=0)
        # the coupling moved charge (by far more than the tolerance) ...
        assert np.abs(coupled[k + 1] - reset - mean_charge).max() > 100.0
        if len(GROUPED[k]) == 3:
            # ... and read by read: coupling the mean read is not the same
            of_mean = reset + ipc_taichi.couple(mean_charge, model=model_file)
            assert np.any(np.abs(of_mean - expect) > 10 * 1e-6 * np.abs(expect))


def test_romanisims_inverse_linearity_follows_the_coupling(scene, cpu):
    """With romanisim's own inverse linearity (a quadratic, per-pixel coefficients), each
    read is the non-linearity of reset + couple(charge); its DQ comes through."""
    from romanisim.models.nonlinearity import Nonlinearity

    coeffs = np.zeros((3,) + scene.shape)
    coeffs[1], coeffs[2] = 1.0, -1e-6  # DN: compresses 2 % at 20000 DN
    coeffs[:, 0, 0] = 0.0  # a pixel with no coefficients: romanisim flags it
    inv_linearity = Nonlinearity(coeffs=coeffs, getdq=True, gain=2.0)
    assert inv_linearity.dq[0, 0] and not inv_linearity.dq[1:].any()
    charge, stock_reset = _uncoupled(scene)
    reset = stock_reset.astype(np.float64)
    # romanisim's own reference read went through the inverse linearity too
    stock, _ = l1.apportion_counts_to_resultants(
        scene, l1.read_pattern_to_tij(READS), inv_linearity=inv_linearity, **LEVELS)
    coupled, dq = ours.apportion_counts_to_resultants(
        scene, l1.read_pattern_to_tij(GROUPED), law="donlon2018",
        inv_linearity=inv_linearity, **LEVELS)
    np.testing.assert_array_equal(coupled[0], stock[0])
    each = inv_linearity.apply(reset + ipc_taichi.couple(charge, law="donlon2018"),
                               electrons=True)
    for k, expect in enumerate(_mean_of_reads(each)):
        np.testing.assert_allclose(coupled[k + 1], expect, rtol=1e-6, atol=0)
    assert np.all(dq[:, 0, 0]) and not dq[:, 1:].any()


def test_make_l1_is_the_coupled_resultants_in_dn(scene, cpu):
    """make_l1 = the coupled resultants / gain, rounded (no read noise); with read noise,
    the reference read (reset level + read noise) is romanisim's own, bit for bit."""
    image = galsim.Image(scene)
    args = dict(pedestal=10000.0, pedestal_extra_noise=8.0, seed=SEED)
    electrons, _ = ours.apportion_counts_to_resultants(
        scene, l1.read_pattern_to_tij(GROUPED), **args)
    dn, dq = ours.make_l1(image, GROUPED, gain=2.0, read_noise=0.0, saturation=1e9, **args)
    np.testing.assert_array_equal(dn, np.round(electrons / np.float32(2.0)))
    assert dq.shape == dn.shape and not dq.any()

    noisy = dict(args, gain=2.0, read_noise=5.0, saturation=1e9, reference_read=True)
    dn, _, reference = ours.make_l1(image, GROUPED, **noisy)
    stock, _, stock_reference = l1.make_l1(image, GROUPED, ipc_model=_Unchanged(), **noisy)
    np.testing.assert_array_equal(reference, stock_reference)
    # the difference is the coupling: about alpha * (star - sky) beside the star
    beside = (dn - stock)[:, 15, 21] * 2.0
    assert np.all(beside > 0.006 * (scene[15, 20] - 3000.0) * np.array([1, 2.5, 5]) / 6)


def _nearest_neighbour_correlation(frame):
    """Correlation of x and y nearest neighbours (pooled) away from the frame's edge,
    and its standard error for independent pixels."""
    d = frame[2:-2, 2:-2] - frame[2:-2, 2:-2].mean()
    pairs = (d[:, 1:] * d[:, :-1]).sum() + (d[1:] * d[:-1]).sum()
    n = d[:, 1:].size + d[1:].size
    return pairs / n / np.mean(d * d), 1.0 / np.sqrt(n)


def test_a_flat_shows_the_coupling_in_its_neighbour_covariance(tmp_path, cpu):
    """A flat ramp (model file, constant alpha = 0.02): the last-minus-first difference
    of romanisim's resultants is correlated between nearest neighbours as the kernel
    [alpha, 1 - 4 alpha, alpha] predicts; without the coupling it is not."""
    alpha = 0.02
    path = tmp_path / "flat_ipc.json"
    CouplingModel.resolve(f"constant:{alpha}").save(path)
    flat = galsim.Image(np.random.default_rng(5).poisson(40000.0, (192, 192)).astype(float))
    args = dict(seed=11, gain=2.0, read_noise=0.0, saturation=1e9)
    dn, _ = ours.make_l1(flat, [[1], [2, 3]], model=str(path), **args)
    stock, _ = l1.make_l1(flat, [[1], [2, 3]], ipc_model=_Unchanged(), **args)

    rho, error = _nearest_neighbour_correlation(dn[1].astype(float) - dn[0])
    rho_stock, _ = _nearest_neighbour_correlation(stock[1].astype(float) - stock[0])
    centre = 1 - 4 * alpha
    predicted = 2 * alpha * centre / (centre ** 2 + 4 * alpha ** 2)  # 0.0434
    assert abs(rho_stock) < 4 * error
    assert abs(rho - predicted) < 4 * error
    assert rho > 8 * error


def test_coupled_context_makes_romanisims_make_l1_ours(scene, model_file, cpu):
    """Inside ``coupled`` the function romanisim.image.simulate calls couples each read
    (its ipc_model dropped); afterwards romanisim's own is back."""
    import inspect

    from romanisim import image as romanisim_image

    # simulate looks make_l1 up on romanisim.l1 when called: where coupled replaces it
    assert "romanisim.l1.make_l1(" in inspect.getsource(romanisim_image.simulate)
    image = galsim.Image(scene)
    args = dict(seed=SEED, gain=2.0, read_noise=3.0)
    stock = l1.make_l1
    expect, _ = ours.make_l1(image, GROUPED, model=model_file, **args)
    with ours.coupled(model=model_file):
        assert l1.make_l1 is not stock
        inside, _ = l1.make_l1(image, GROUPED, ipc_model=None, **args)
        outer = l1.make_l1
        with ours.coupled(law="constant:0.01"):
            assert l1.make_l1 not in (stock, outer)
        assert l1.make_l1 is outer  # an inner context leaves the outer one in place
    assert l1.make_l1 is stock
    np.testing.assert_array_equal(inside, expect)


SCRIPT = """
import sys
import galsim
import numpy as np
from romanisim import l1
counts = galsim.Image(np.load(sys.argv[1]))
dn, _ = l1.make_l1(counts, [[1], [2, 3], [4, 5, 6]], seed=7, gain=2.0, read_noise=3.0)
np.save(sys.argv[2], dn)
"""


def test_the_command_runs_a_romanisim_script_coupled(scene, model_file, tmp_path, cpu):
    """``python -m ipc_taichi.romanisim --model FILE SCRIPT ARGS``: the script's
    romanisim.l1.make_l1 couples each read (the script's own arguments passed through)."""
    script = tmp_path / "ramp.py"
    script.write_text(SCRIPT)
    np.save(tmp_path / "counts.npy", scene)
    out = tmp_path / "dn.npy"
    assert ours.main(["--model", model_file, str(script), str(tmp_path / "counts.npy"),
                      str(out)]) == 0
    expect, _ = ours.make_l1(galsim.Image(scene), GROUPED, model=model_file, seed=SEED,
                             gain=2.0, read_noise=3.0)
    np.testing.assert_array_equal(np.load(out), expect)
    assert not hasattr(l1.make_l1, "stock")  # romanisim's own again


def test_refusals(scene, tmp_path, capsys):
    with pytest.raises(ipc_taichi.IPCInputError, match="ipc_model"):
        ours.make_l1(galsim.Image(scene), GROUPED, ipc_model=_Unchanged())
    hook = ours.ReadCoupling(CouplingModel.resolve("donlon2018"), np.zeros(scene.shape))
    with pytest.raises(ipc_taichi.IPCInputError, match="electrons"):
        hook.apply(scene)
    missing = str(tmp_path / "missing.json")
    assert ours.main(["--model", missing, "romanisim-make-image", "x.asdf"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "missing.json" in err
    assert ours.main(["--law", "donlon2018", "no-such-romanisim-command"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no-such-romanisim-command" in err
