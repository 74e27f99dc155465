"""CUDA path: the same kernels, arch chosen at init. Runs only where CUDA exists
(``make test-gpu``); the CPU tests in test_device_arrays.py run the same API
and the same engine path without a GPU."""

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import engine
from ipc_taichi.engine import get_frame_kernels
from ipc_taichi.reference import couple_reference

pytestmark = pytest.mark.gpu


def _torch_cuda():
    torch = pytest.importorskip("torch")
    if not torch.cuda.is_available():
        pytest.skip("PyTorch has no CUDA here (a CPU build)")
    return torch


@pytest.mark.parametrize("precision, rtol", [("f64", 1e-10), ("f32", 1e-5)])
def test_cuda_matches_reference(precision, rtol):
    rng = np.random.default_rng(1)
    truth = rng.uniform(0, 60000, (300, 257))
    measured = ipc_taichi.couple(truth, arch="cuda", precision=precision)
    assert ipc_taichi.runtime.current().arch == "cuda"
    np.testing.assert_allclose(measured, couple_reference(truth), rtol=rtol, atol=rtol * 6e4)
    signal, info = ipc_taichi.decouple(measured, arch="cuda", precision=precision,
                                       full_output=True)
    assert info.converged
    assert np.abs(signal - truth).max() < (0.05 if precision == "f64" else 0.05 + 6e4 * 1e-6)


def test_cuda_tiled_and_f32_exp():
    """On CUDA: tiled == whole frame, and the f32 path stays accurate."""
    from ipc_taichi.tiling import decouple_tiled

    rng = np.random.default_rng(2)
    truth = rng.uniform(0, 60000, (257, 300))
    measured = couple_reference(truth)
    whole = ipc_taichi.decouple(measured, arch="cuda", precision="f64")
    tiled = decouple_tiled(measured, 64, arch="cuda", precision="f64")
    assert np.abs(tiled - whole).max() <= 1e-12 * whole.max()
    fast = ipc_taichi.decouple(measured, arch="cuda", precision="f32")
    assert np.abs(fast - truth).max() < 0.05 + 6e4 * 1e-6


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_torch_cuda_tensors_stay_on_the_device(precision):
    torch = _torch_cuda()
    rng = np.random.default_rng(3)
    truth = rng.uniform(0, 60000, (2, 190, 233))
    truth[1, 7, 9] = np.nan
    mask = np.zeros((190, 233), bool)
    mask[50, 60] = True
    measured = ipc_taichi.couple(truth, arch="cuda", precision=precision, mask=mask)
    want = ipc_taichi.decouple(measured, arch="cuda", precision=precision, mask=mask)
    t = torch.from_numpy(measured).cuda()
    got = ipc_taichi.decouple(t, arch="cuda", precision=precision,
                              mask=torch.from_numpy(mask).cuda())
    assert got.is_cuda and got.shape == t.shape
    assert got.dtype == (torch.float64 if precision == "f64" else torch.float32)
    assert np.array_equal(got.cpu().numpy(), want, equal_nan=True)  # same kernels, same bits
    coupled = ipc_taichi.couple(torch.from_numpy(truth).cuda(), arch="cuda",
                                precision=precision, mask=mask)
    assert coupled.is_cuda and np.array_equal(coupled.cpu().numpy(), measured, equal_nan=True)


def test_cupy_arrays_round_trip():
    cupy = pytest.importorskip("cupy")
    _torch_cuda()
    rng = np.random.default_rng(4)
    truth = rng.uniform(0, 60000, (128, 160))
    measured = couple_reference(truth)
    want = ipc_taichi.decouple(measured, arch="cuda", precision="f64")
    got = ipc_taichi.decouple(cupy.asarray(measured), arch="cuda", precision="f64")
    assert isinstance(got, cupy.ndarray)
    assert np.array_equal(cupy.asnumpy(got), want)


def test_stack_reuses_buffers_and_compiles_nothing_new():
    rng = np.random.default_rng(5)
    cube = np.stack([couple_reference(f) for f in rng.uniform(0, 60000, (6, 200, 180))])
    ipc_taichi.init("cuda", "f32")
    engine.clear_workspaces()
    first, infos = ipc_taichi.decouple(cube, arch="cuda", precision="f32", full_output=True)
    cache = engine.workspace_cache_info()
    kernels = get_frame_kernels("f32")
    compiled = [len(k._primal.compiled_kernels) for k in (kernels.load, kernels.store)]
    again = ipc_taichi.decouple(cube, arch="cuda", precision="f32")
    assert len(cache) == 1 and engine.workspace_cache_info() == cache
    assert [len(k._primal.compiled_kernels) for k in (kernels.load, kernels.store)] == compiled
    assert np.array_equal(first, again) and len(infos) == 6
    for k in range(6):
        assert np.array_equal(first[k], ipc_taichi.decouple(cube[k], arch="cuda",
                                                            precision="f32"))


def test_pinned_buffers_and_device_memory():
    ipc_taichi.init("cuda", "f64")
    rng = np.random.default_rng(6)
    measured = couple_reference(rng.uniform(0, 60000, (1024, 1024)))
    want = ipc_taichi.decouple(measured, arch="cuda", precision="f64")
    pin_in = engine.pinned_empty(measured.shape, np.float64)
    pin_in[...] = measured
    pin_out = engine.pinned_empty(measured.shape, np.float64)
    engine.clear_workspaces()
    free0 = engine.cuda_driver().memory()[0]
    got = ipc_taichi.decouple(pin_in, arch="cuda", precision="f64", out=pin_out)
    used = free0 - engine.cuda_driver().memory()[0]
    assert got is pin_out and np.array_equal(got, want)
    (nbytes,) = engine.workspace_cache_info().values()
    assert nbytes <= 3.5 * measured.nbytes
    print(f"device memory taken by the call: {used / measured.nbytes:.2f}x the frame")


def test_cuda_bench_section_small():
    from ipc_taichi import runtime
    from ipc_taichi.bench import measure_cuda, render_cuda

    try:
        cuda = measure_cuda(size=512, repeats=2, stack=2)
    finally:
        runtime.init("cuda", "f64")
    rows = {(r["row"], r["precision"]): r for r in cuda["rows"]}
    for prec in ("f64", "f32"):
        host = rows[("host in/out (NumPy)", prec)]
        assert host["max_error"] < 0.05 and host["iterations"] >= 3
        peer = rows.get(("CuPy peer, device-resident", prec))
        if peer is not None:
            assert peer["iterations"] == host["iterations"]
            assert abs(peer["max_error"] - host["max_error"]) < 0.01
    assert "## CUDA" in render_cuda(cuda)


def _decouple_on_worker(frame):
    import os

    import ipc_taichi

    return os.environ["CUDA_VISIBLE_DEVICES"], ipc_taichi.decouple(frame, arch="cuda")


def test_one_worker_per_gpu():
    """Every GPU of this machine gets one worker that decouples on it."""
    distributed = pytest.importorskip("distributed")  # not in every GPU image
    Client = distributed.Client

    from ipc_taichi.gpus import gpu_cluster, visible_gpus

    gpus = visible_gpus()
    rng = np.random.default_rng(7)
    frame = couple_reference(rng.uniform(0, 60000, (96, 80)))
    want = ipc_taichi.decouple(frame, arch="cuda", precision="f64")
    with gpu_cluster(gpus, use_dask_cuda=False) as cluster, Client(cluster) as client:
        workers = list(client.scheduler_info()["workers"])
        futures = [client.submit(_decouple_on_worker, frame, workers=[w], pure=False)
                   for w in workers]
        results = client.gather(futures)
    assert sorted(g for g, _ in results) == sorted(gpus)
    for _, got in results:
        assert np.abs(got - want).max() <= 1e-12 * want.max()


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_constant_law_kernel_on_cuda(precision):
    """The constant-law kernel on CUDA: the general kernel's results (a law
    whose exponential terms vanish against its floor takes the general one)."""
    from ipc_taichi import ParametricLaw

    rng = np.random.default_rng(8)
    measured = couple_reference(rng.uniform(0, 60000, (257, 300)), law="constant:0.0125")
    const = ipc_taichi.decouple(measured, law="constant:0.0125", arch="cuda",
                                precision=precision)
    general = ipc_taichi.decouple(measured, law=ParametricLaw(1e-300, 1e4, 0.0, 1e4, 0.0125),
                                  arch="cuda", precision=precision)
    rtol = 1e-12 if precision == "f64" else 1e-6
    np.testing.assert_allclose(const, general, rtol=rtol, atol=rtol * 6e4)


def test_work_follows_the_callers_torch_stream():
    """A tensor made on a side stream and used there: decouple waits for it
    and the side stream waits for the result (no host synchronisation)."""
    torch = _torch_cuda()
    rng = np.random.default_rng(9)
    measured = couple_reference(rng.uniform(0, 60000, (1024, 1024)))
    want = ipc_taichi.decouple(measured, arch="cuda", precision="f64")
    side = torch.cuda.Stream()
    with torch.cuda.stream(side):
        host = torch.from_numpy(measured).pin_memory()
        t = torch.zeros_like(host, device="cuda")
        for _ in range(20):  # keep the side stream busy before the data lands
            t.mul_(1.0)
        t.copy_(host, non_blocking=True)
        got = ipc_taichi.decouple(t, arch="cuda", precision="f64")
        total = got.sum()  # on the side stream, after the result is ready
    side.synchronize()
    assert np.array_equal(got.cpu().numpy(), want)
    assert abs(float(total) - want.sum()) <= 1e-9 * abs(want.sum())  # summed on the GPU


def test_wide_frames_and_out_as_input_on_cuda():
    """The tree's capacity made small (2**5 partials): maxima still of the
    whole frame; and out= given as the input keeps its bad pixels."""
    torch = _torch_cuda()
    rng = np.random.default_rng(10)
    signal = rng.uniform(0, 1000, (64, 300))
    signal[40, 290] = 60000.0
    measured = couple_reference(signal)
    ref, ref_info = ipc_taichi.decouple(measured, arch="cuda", precision="f64", full_output=True)
    with engine.reduction_fan_in(2):
        got, info = ipc_taichi.decouple(measured, arch="cuda", precision="f64",
                                        full_output=True)
    np.testing.assert_allclose(info.max_signal, ref_info.max_signal, rtol=1e-12)
    assert np.array_equal(got, ref)
    measured[3, 4] = np.nan
    t = torch.from_numpy(measured).cuda()
    mask = np.zeros(measured.shape, bool)
    mask[10, 11] = True
    want = ipc_taichi.decouple(measured, arch="cuda", precision="f64", mask=mask)
    back = ipc_taichi.decouple(t, arch="cuda", precision="f64", mask=mask, out=t)
    assert back.data_ptr() == t.data_ptr()
    assert np.array_equal(t.cpu().numpy(), want, equal_nan=True)
    assert t[10, 11].item() == measured[10, 11]


def test_copy_policies_and_steps_ahead_give_the_same_bits():
    """Staged copies (the default), page-locked per call and pageable copies
    give the same result; so do steps launched ahead of the stopping rule's
    decision and steps waited for one by one (a callback makes the engine
    wait); and the result is the NumPy reference's to 1e-10."""
    from ipc_taichi.reference import decouple_reference

    rng = np.random.default_rng(11)
    measured = couple_reference(rng.uniform(0, 60000, (1100, 1030)))  # above PIN_MIN_BYTES
    want, info = ipc_taichi.decouple(measured, arch="cuda", precision="f64", full_output=True)
    for policy in ("register", "pageable"):
        with engine.copy_policy(policy):
            got = ipc_taichi.decouple(measured, arch="cuda", precision="f64")
        assert np.array_equal(got, want), policy
    seen = []
    got = ipc_taichi.decouple(measured, arch="cuda", precision="f64",
                              callback=lambda q, estimate: seen.append(q))
    assert np.array_equal(got, want) and seen == list(range(1, info.iterations + 1))
    ref, iterations = decouple_reference(measured)[:2]
    assert iterations == info.iterations
    assert np.abs(want - ref).max() <= 1e-10 * np.abs(ref).max()
