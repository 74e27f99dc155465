"""Dask: a 2-worker local cluster gives the single-process results."""

import os

import numpy as np
import pytest
from astropy.io import fits

import ipc_taichi
from ipc_taichi.cluster import decouple_files, decouple_mosaic, decouple_stack
from ipc_taichi.reference import couple_reference

pytestmark = pytest.mark.filterwarnings(
    # distributed's own shutdown/port noise, not ours to fix
    "ignore::ResourceWarning", "ignore:Port 8787:UserWarning",
    "ignore:.*clean up.*:UserWarning")


@pytest.fixture(scope="module")
def client():
    from ipc_taichi.cluster import close_client, local_client

    c = local_client(workers=2)
    yield c
    close_client(c)


def test_workers_are_single_threaded_processes(client):
    info = client.scheduler_info()["workers"]
    assert len(info) == 2
    assert all(w["nthreads"] == 1 for w in info.values())
    pids = client.run(os.getpid)
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()


def test_files_identical_to_single_process(client, tmp_path, rng):
    pairs, truths = [], []
    for k in range(3):
        truth = rng.uniform(0, 60000, (30 + k, 41))
        src = tmp_path / f"in{k}.fits"
        fits.writeto(src, couple_reference(truth))
        pairs.append((str(src), str(tmp_path / f"out{k}.fits")))
        truths.append(truth)
    bad = tmp_path / "corrupt.fits"
    bad.write_bytes(b"SIMPLE  =                    T" + b"\0" * 100)
    pairs.append((str(bad), str(tmp_path / "corrupt_out.fits")))
    options = dict(law="donlon2018", geometry="nearest", edge="zero", max_iter=20, tol=1e-5,
                   arch="cpu", precision="f64")
    results = decouple_files(pairs, options, client)
    assert [r["ok"] for r in results] == [True, True, True, False]
    assert "corrupt.fits" in results[3]["error"] and "\n" not in results[3]["error"]
    assert not os.path.exists(pairs[3][1])
    ipc_taichi.init("cpu", "f64")
    for (src, dst), _truth, res in zip(pairs, truths, results):
        single, info = ipc_taichi.decouple(fits.getdata(src), full_output=True)
        np.testing.assert_array_equal(fits.getdata(dst), single)
        assert res["iterations"] == info.iterations and res["converged"]
        assert fits.getheader(dst)["IPCARCH"] == "cpu"


def test_stack_identical(client, rng, cpu):
    cube = np.stack([couple_reference(rng.uniform(0, 60000, (24, 20))) for _ in range(3)])
    got = decouple_stack(cube, client, arch="cpu", precision="f64")
    np.testing.assert_array_equal(got, ipc_taichi.decouple(cube))


def test_mosaic_map_overlap_identical(client, cpu):
    from ipc_taichi.datasets import star_field

    truth = star_field(96, seed=5, n_per_mpix=20000)
    measured = couple_reference(truth)
    whole, info = ipc_taichi.decouple(measured, full_output=True)
    got, minfo = decouple_mosaic(measured, client, chunk=40, arch="cpu", precision="f64",
                                 full_output=True)
    assert minfo.iterations == info.iterations and minfo.converged
    assert np.abs(got - whole).max() <= 1e-12 * whole.max()


def test_mosaic_and_stack_with_a_bond_map_identical(client, cpu):
    """Each Dask block gets the map cropped with its overlap (the tiles of the
    iteration count too), a stack's frames the same map: the whole frame's
    results."""
    from ipc_taichi.datasets import star_field
    from tests.test_bondmap_engine import mapped

    truth = star_field(80, seed=6, n_per_mpix=20000)
    model = mapped("donlon2018", None, "zero", truth.shape, seed=11)
    measured = couple_reference(truth, model=model)
    whole, info = ipc_taichi.decouple(measured, model=model, full_output=True)
    got, minfo = decouple_mosaic(measured, client, chunk=33, arch="cpu", precision="f64",
                                 full_output=True, model=model)
    assert minfo.iterations == info.iterations and minfo.converged
    assert np.abs(got - whole).max() <= 1e-12 * whole.max()
    assert np.abs(whole - truth).max() < 0.05
    cube = np.stack([measured, measured[::-1, ::-1].copy()])
    stack = decouple_stack(cube, client, arch="cpu", precision="f64", model=model)
    np.testing.assert_array_equal(stack, ipc_taichi.decouple(cube, model=model))


def _die_on_name(src, dst, options):
    """The per-file task, except that a file named *die* kills its worker."""
    from ipc_taichi.cluster import decouple_one_file

    if "die" in os.path.basename(src):
        os._exit(1)
    return decouple_one_file(src, dst, options)


def test_dying_worker_fails_only_its_file(client, tmp_path, rng):
    import sys

    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import tests
    options = dict(law="donlon2018", geometry="nearest", edge="zero", max_iter=20, tol=1e-5,
                   arch="cpu", precision="f64")
    pairs = []
    for name in ("good1", "die", "good2"):
        src = tmp_path / f"{name}.fits"
        fits.writeto(src, couple_reference(rng.uniform(0, 60000, (20, 20))))
        pairs.append((str(src), str(tmp_path / f"{name}_out.fits")))
    results = decouple_files(pairs, options, client, task=_die_on_name)
    assert [r["ok"] for r in results] == [True, False, True]
    assert "died" in results[1]["error"] and "die.fits" in results[1]["error"]
    assert not os.path.exists(pairs[1][1])
    assert os.path.exists(pairs[0][1]) and os.path.exists(pairs[2][1])
    client.wait_for_workers(2, timeout=60)  # the nanny restarts the dead worker


def test_mosaic_refuses_law_with_model(rng):
    """As ipc_taichi.decouple: a model and a law together are refused, not
    one silently ignored (checked before any work, so no client is needed)."""
    from ipc_taichi import IPCInputError
    from ipc_taichi.model import CouplingModel

    frame = rng.uniform(0, 1000, (16, 16))
    model = CouplingModel.resolve("constant:0.01")
    with pytest.raises(IPCInputError, match="not both"):
        decouple_mosaic(frame, None, chunk=8, law="constant:0.02", model=model)


def test_product_options_refuse_unknown_names():
    from ipc_taichi import IPCInputError
    from ipc_taichi.products import ProductOptions

    with pytest.raises(IPCInputError, match="unknown product option"):
        ProductOptions.from_kwargs(gian=2.0)
    options = ProductOptions.from_kwargs(gain=2.0, dq_bits=None, output_dtype="same")
    assert options.gain == 2.0 and options.dq_bits == "DO_NOT_USE,SATURATED"
    assert options.output_dtype is None
