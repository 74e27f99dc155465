"""The device-array API and the GPU engine's code path, run on the CPU.

PyTorch CPU tensors take the same path as CUDA tensors (handed to Taichi without
a copy, result in a new tensor on the same device); the engine path with Taichi
ndarrays and explicit host<->device copies (the one NumPy input takes on CUDA)
is run on the CPU by forcing it; DLPack producers (CuPy, JAX) are stood in for
by a wrapper around a NumPy array; page-locking is checked against a stand-in
CUDA driver. Results must be bit-identical to the NumPy path.
"""

import ctypes
import gc
import os
import sys
import types

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import IPCInputError, engine
from ipc_taichi.engine import (
    FAN_IN,
    get_frame_kernels,
    get_reduce_kernel,
    get_step_kernel,
)
from ipc_taichi.reference import couple_reference, decouple_reference
from tests.helpers import same


@pytest.fixture
def frames(rng):
    """A 3-frame stack with a NaN pixel, and a mask."""
    truth = rng.uniform(0, 60000, (3, 41, 37))
    truth[1, 5, 6] = np.nan
    mask = np.zeros((41, 37), bool)
    mask[20, 11] = True
    return truth, mask


@pytest.fixture
def device_path():
    """Run NumPy inputs through Taichi ndarrays and explicit copies (the CUDA path)."""
    with engine.device_buffers():
        engine.clear_workspaces()
        yield
        engine.clear_workspaces()


def test_torch_tensors_round_trip_bit_identical(cpu, frames, torch):
    truth, mask = frames
    measured = ipc_taichi.couple(truth, mask=mask)
    measured_t = ipc_taichi.couple(torch.from_numpy(truth), mask=mask)
    assert isinstance(measured_t, torch.Tensor) and measured_t.dtype == torch.float64
    assert measured_t.shape == truth.shape and same(measured_t, measured)
    signal, infos = ipc_taichi.decouple(measured, mask=mask, full_output=True)
    signal_t, infos_t = ipc_taichi.decouple(torch.from_numpy(measured),
                                            mask=torch.from_numpy(mask), full_output=True)
    assert isinstance(signal_t, torch.Tensor) and same(signal_t, signal)
    assert [i.max_delta for i in infos_t] == [i.max_delta for i in infos]
    assert np.isnan(signal_t[1, 5, 6].item())
    assert signal_t[0, 20, 11].item() == measured[0, 20, 11]  # masked: kept as given
    good = np.isfinite(truth) & ~mask
    assert np.abs(signal_t.numpy() - truth)[good].max() < 0.05


def test_torch_frame_f32_and_integer_input(cpu, rng, torch):
    truth = rng.uniform(0, 60000, (30, 20))
    measured = couple_reference(truth)
    one = ipc_taichi.decouple(torch.from_numpy(measured).float())
    assert one.shape == (30, 20) and one.dtype == torch.float64  # the runtime precision
    assert same(one, ipc_taichi.decouple(measured.astype(np.float32)))
    ints = torch.from_numpy(np.rint(truth).astype(np.int32))
    assert same(ipc_taichi.couple(ints), ipc_taichi.couple(np.rint(truth)))
    graded = torch.from_numpy(measured).requires_grad_()
    assert same(ipc_taichi.decouple(graded), ipc_taichi.decouple(measured))


def test_device_path_on_cpu_bit_identical(cpu, frames, device_path, monkeypatch):
    truth, mask = frames
    host_measured = np.stack([couple_reference(f) for f in np.nan_to_num(truth)])
    with engine.device_buffers(False):
        want_c = ipc_taichi.couple(truth, mask=mask)
        want_d, want_info = ipc_taichi.decouple(host_measured, mask=mask, full_output=True)
    calls = {"up": 0, "down": 0}
    up, down = engine.HostCopies.upload, engine.HostCopies.download

    def count_up(self, nd, host):
        calls["up"] += host.size > 4  # frames and masks, not the 2-number reads
        return up(self, nd, host)

    def count_down(self, host, nd):
        calls["down"] += host.size > 4
        return down(self, host, nd)

    monkeypatch.setattr(engine.HostCopies, "upload", count_up)
    monkeypatch.setattr(engine.HostCopies, "download", count_down)
    got_c = ipc_taichi.couple(truth, mask=mask)
    assert same(got_c, want_c)
    assert calls == {"up": 6, "down": 3}  # per frame: frame + mask up, result down
    calls.update(up=0, down=0)
    got_d, got_info = ipc_taichi.decouple(host_measured, full_output=True, mask=mask)
    assert same(got_d, want_d) and calls == {"up": 6, "down": 3}
    assert [i.max_delta for i in got_info] == [i.max_delta for i in want_info]
    # a strided f32 view is converted once into the workspace's staging frame
    view = host_measured.astype(np.float32)[:, ::-1, :]
    with engine.device_buffers(False):
        want_v = ipc_taichi.decouple(view)
    assert same(ipc_taichi.decouple(view), want_v)


def test_callback_sees_the_same_estimates_on_device_path(cpu, rng, device_path):
    measured = couple_reference(rng.uniform(0, 60000, (25, 31)))
    seen = {}
    for forced in (False, True):
        seen[forced] = []
        with engine.device_buffers(forced):
            ipc_taichi.decouple(measured,
                                callback=lambda q, e, s=seen[forced]: s.append(e.copy()))
    assert len(seen[True]) == len(seen[False]) >= 3
    assert all(np.array_equal(a, b) for a, b in zip(seen[True], seen[False]))


def test_buffers_reused_and_nothing_compiled_twice(cpu, rng, device_path):
    measured = np.stack([couple_reference(f) for f in rng.uniform(0, 60000, (4, 33, 29))])
    with engine.step_kernels_built() as built:
        ipc_taichi.decouple(measured[0])
    before = dict(engine.workspace_cache_info())
    workspaces = engine.cached_workspaces()
    config, = set(built)  # the layout this path runs, flat or not
    assert config.offsets == ((0, 1), (1, 0)) and config.law_kind == "parametric"
    step = get_step_kernel(config)
    frame_kernels = get_frame_kernels("f64")
    kernels = [step, frame_kernels.load, frame_kernels.store]
    compiled = [len(k._primal.compiled_kernels) for k in kernels]
    assert all(n >= 1 for n in compiled)  # (one per argument kind: NumPy, ndarray, tensor)
    ipc_taichi.decouple(measured)  # a stack: every frame in the same buffers
    ipc_taichi.decouple(measured[1] * 1.01)
    ipc_taichi.couple(measured[2])
    assert engine.workspace_cache_info() == before
    assert engine.cached_workspaces()[0] is workspaces[0]
    assert [len(k._primal.compiled_kernels) for k in kernels] == compiled


def test_workspace_memory_is_bounded(cpu, device_path):
    """Buffers of the device path: io + two padded estimates + ok bytes + partials."""
    frame = np.ones((256, 256))
    ipc_taichi.decouple(frame, layout="pixel", max_iter=2, tol=0)
    (nbytes,) = engine.workspace_cache_info().values()
    assert nbytes <= 3.5 * frame.nbytes


def test_tree_reduction_is_exact(cpu, rng):
    reduce_partials = get_reduce_kernel("f64")
    for n in (1, 2, FAN_IN - 1, FAN_IN, FAN_IN + 1, FAN_IN ** 2 + 3, 40000):
        part = rng.uniform(-1, 1, (n + 5, 2))
        part[n:] = 9.0  # beyond n: must be ignored
        k0, k1 = rng.integers(0, n, 2)
        part[k0, 0], part[n - 1, 1] = 5.0, 7.0  # one maximum at the very end (clamping)
        want = part[:n].max(axis=0)
        reduce_partials(part, n)
        assert part[0, 0] == want[0] and part[0, 1] == want[1], n


def test_pixel_layout_independent_of_run_height(cpu, rng):
    """Column runs carry the vertical pairs' alphas in registers; cutting the
    columns into short runs must not change a bit (second neighbours too)."""
    g = ipc_taichi.Geometry.terms(horizontal=1.0, vertical=0.9, diagonal=0.1, second=0.02)
    truth = rng.uniform(0, 60000, (45, 38))
    measured = couple_reference(truth, geometry=g)
    long_runs = ipc_taichi.decouple(measured, geometry=g, layout="pixel", max_iter=4, tol=0)
    with engine.pixel_runs(threads=64, min_rows=1):
        short_runs = ipc_taichi.decouple(measured, geometry=g, layout="pixel", max_iter=4,
                                         tol=0)
        (ws,) = engine.cached_workspaces()
        assert ws.strip < 45 and ws.n_partials > 38
    assert np.array_equal(short_runs, long_runs)
    ref = decouple_reference(measured, geometry=g, max_iter=4, tol=0)[0]
    assert np.abs(long_runs - ref).max() <= 1e-10 * measured.max()
    engine.clear_workspaces()


def test_out_argument(cpu, rng, torch):
    measured = np.stack([couple_reference(f) for f in rng.uniform(0, 60000, (2, 20, 24))])
    out = np.empty_like(measured)
    got = ipc_taichi.decouple(measured, out=out)
    assert got is out and same(out, ipc_taichi.decouple(measured))
    frame_out = np.empty_like(measured[0])  # a frame's out is given back itself too
    assert ipc_taichi.decouple(measured[0], out=frame_out) is frame_out
    assert ipc_taichi.couple(measured[0], out=frame_out) is frame_out
    with pytest.raises(IPCInputError, match="out: expected"):
        ipc_taichi.decouple(measured, out=np.empty((2, 20, 23)))
    tout = torch.empty(20, 24, dtype=torch.float64)
    got_t = ipc_taichi.couple(torch.from_numpy(measured[0]), out=tout)
    assert got_t.data_ptr() == tout.data_ptr()
    assert same(tout, ipc_taichi.couple(measured[0]))


def test_tensor_on_another_device_is_refused(cpu, torch):
    with pytest.raises(IPCInputError, match="Taichi runs on the CPU"):
        ipc_taichi.decouple(torch.empty((8, 8), device="meta"))
    with pytest.raises(IPCInputError, match="not a real number type"):
        ipc_taichi.decouple(torch.zeros((8, 8), dtype=torch.complex64))
    with pytest.raises(IPCInputError, match="2-D frame"):
        ipc_taichi.couple(torch.zeros(8))
    with pytest.raises(IPCInputError, match="mask of shape"):
        ipc_taichi.couple(torch.zeros((4, 4)), mask=np.zeros((3, 3), bool))


class _Producer:
    """A stand-in for a CuPy/JAX array: DLPack only, module chosen by the test."""

    def __init__(self, array):
        self._array = array
        self.shape = array.shape

    def __dlpack__(self, **kwargs):
        return self._array.__dlpack__(**kwargs)

    def __dlpack_device__(self):
        return self._array.__dlpack_device__()


@pytest.fixture
def fake_cupy(monkeypatch):
    cls = type("ndarray", (_Producer,), {"__module__": "cupy"})
    module = types.ModuleType("cupy")
    module.from_dlpack = lambda t: cls(np.from_dlpack(t))
    monkeypatch.setitem(sys.modules, "cupy", module)
    return cls


def test_dlpack_arrays_go_through_torch_and_come_back(cpu, frames, fake_cupy, torch):
    truth, mask = frames
    want = ipc_taichi.couple(truth, mask=mask)
    got = ipc_taichi.couple(fake_cupy(truth), mask=mask)
    assert type(got) is fake_cupy and same(got._array, want)
    assert engine.kind_of(fake_cupy(truth)) == "cupy"
    # an unknown DLPack producer gets a torch tensor back (its module has no from_dlpack)
    generic = ipc_taichi.couple(_Producer(truth[0]), mask=mask)
    assert isinstance(generic, torch.Tensor) and same(generic, want[0])


def test_dlpack_without_torch_says_what_to_install(cpu, frames, fake_cupy, monkeypatch):
    monkeypatch.setitem(sys.modules, "torch", None)  # import torch now fails
    with pytest.raises(IPCInputError, match=r"^ipc_taichi: CuPy arrays .*pip install torch"):
        ipc_taichi.decouple(fake_cupy(frames[0]))


def test_kind_of():
    assert engine.kind_of(np.zeros(2)) == "numpy"
    assert engine.kind_of([[1.0]]) == "numpy"
    assert engine.kind_of(np.ma.zeros(2)) == "numpy"
    assert engine.kind_of(_Producer(np.zeros(2))) == "dlpack"
    # decided from the type's module: no optional package is imported
    assert engine.kind_of(type("Tensor", (), {"__module__": "torch"})()) == "torch"
    assert engine.kind_of(type("Array", (), {"__module__": "jaxlib.xla"})()) == "jax"


class _FakeLib:
    """A stand-in CUDA driver: records page-locking and refuses double locks."""

    def __init__(self):
        self.locked = {}
        self.calls = []

    def cuInit(self, flags):
        return 0

    def cuDeviceGet(self, dev, ordinal):
        return 0

    def cuDevicePrimaryCtxRetain(self, ctx, dev):
        return 0

    def cuCtxPushCurrent_v2(self, ctx):
        return 0

    def cuCtxPopCurrent_v2(self, ctx):
        return 0

    def cuMemHostRegister_v2(self, address, nbytes, flags):
        self.calls.append(("register", address.value))
        lo, hi = address.value, address.value + nbytes.value
        if any(lo < a + n and a < hi for a, n in self.locked.items()):  # as CUDA: overlap
            return engine.CUDA_ERROR_HOST_MEMORY_ALREADY_REGISTERED
        self.locked[address.value] = nbytes.value
        return 0

    def cuMemHostUnregister(self, address):
        self.calls.append(("unregister", address.value))
        return 0 if self.locked.pop(address.value, None) is not None else 713

    def cuMemcpyHtoD_v2(self, dst, src, nbytes):
        return 1  # CUDA_ERROR_INVALID_VALUE

    def cuGetErrorName(self, code, name):
        return 1


def test_pinning_locks_once_and_unlocks_what_it_locked():
    driver = engine.CudaDriver(_FakeLib())
    big = np.zeros(engine.PIN_MIN_BYTES // 8 + 1)
    small = np.zeros(16)
    user = engine.pinned_empty((engine.PIN_MIN_BYTES // 8,), arch="cuda", driver=driver)
    user_address = user.ctypes.data
    assert driver.lib.locked == {user_address: user.nbytes}
    big_pages = big.ctypes.data
    with engine.pinned_for_call([big, big[10:], small, user], "cuda", driver=driver) as pins:
        assert set(driver.lib.locked) == {big_pages, user_address}
        assert pins.locked == [big_pages]  # the view shares big's lock
    assert driver.lib.locked == {user_address: user.nbytes}  # the user's lock stays
    with pytest.raises(KeyError):
        with engine.pinned_for_call([big], "cuda", driver=driver):
            raise KeyError("boom")
    assert driver.lib.locked == {user_address: user.nbytes}  # unlocked on error too
    with engine.pinned_for_call([big], "cpu", driver=driver):
        assert driver.lib.locked == {user_address: user.nbytes}  # a no-op off CUDA
    del user
    gc.collect()
    assert driver.lib.locked == {}  # unlocked when the array is collected
    with pytest.raises(RuntimeError, match="cuMemcpyHtoD failed with error 1"):
        driver.upload(0, big.ctypes.data, 8)
    driver.lib.cuMemHostRegister_v2 = lambda *args: 1  # the driver refuses to lock
    with engine.pinned_for_call([big], "cuda", driver=driver) as pins:
        assert pins.locked == []  # copied from pageable memory instead, no error


def test_pinning_locks_a_views_span_not_its_parent_stack():
    driver = engine.CudaDriver(_FakeLib())
    stack = np.zeros((8, 512, 1024 + 3))  # 8 frames of 4.2 MB
    frame = stack[5]
    with engine.pinned_for_call([frame], "cuda", driver=driver) as pins:
        assert driver.lib.locked == {frame.ctypes.data: frame.nbytes}  # not the 34 MB stack
        assert pins.locked == [frame.ctypes.data]
    assert driver.lib.locked == {}
    column = stack[:, :, 7]  # strided: from its first to its last element
    with engine.pinned_for_call([column], "cuda", driver=driver):
        (address, nbytes), = driver.lib.locked.items()
        assert address == column.ctypes.data
        assert nbytes == (column.size - 1) * 8 * (1024 + 3) + 8


def test_pinning_interrupted_unlocks_what_it_locked():
    lib = _FakeLib()
    driver = engine.CudaDriver(lib)
    first, second = np.zeros(engine.PIN_MIN_BYTES // 8), np.zeros(engine.PIN_MIN_BYTES // 8)
    register = lib.cuMemHostRegister_v2

    def interrupted(address, nbytes, flags):
        if lib.locked:  # Ctrl-C while locking the second array
            raise KeyboardInterrupt
        return register(address, nbytes, flags)

    lib.cuMemHostRegister_v2 = interrupted
    with pytest.raises(KeyboardInterrupt):
        with engine.pinned_for_call([first, second], "cuda", driver=driver):
            pass  # pragma: no cover (never entered)
    assert lib.locked == {}
    assert ("unregister", first.ctypes.data) in lib.calls


def test_ndarray_pointer_addresses_taichi_memory(cpu):
    import taichi as ti

    nd = ti.ndarray(ti.f64, (3, 4))
    copies = engine.HostCopies("cpu")
    host = np.arange(12.0).reshape(3, 4)
    copies.upload(nd, host)
    assert np.array_equal(nd.to_numpy(), host)
    back = np.empty_like(host)
    copies.download(back, nd)
    assert np.array_equal(back, host)
    with pytest.raises(ValueError, match="C-contiguous"):
        copies.upload(nd, host.T)


def test_gpu_cluster_pins_one_worker_per_gpu(monkeypatch):
    """Each worker sees exactly its own GPU (checked with GPU ids only: the
    workers start without touching CUDA)."""
    from distributed import Client

    from ipc_taichi.gpus import gpu_cluster, visible_gpus

    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3,5")
    assert visible_gpus() == ["3", "5"]
    with gpu_cluster(use_dask_cuda=False) as cluster, Client(cluster) as client:
        seen = client.run(lambda: (os.environ["CUDA_VISIBLE_DEVICES"],
                                   os.environ["IPC_TAICHI_ARCH"]))
        threads = client.nthreads()
    assert sorted(seen.values()) == [("3", "cuda"), ("5", "cuda")]
    assert sorted(threads.values()) == [1, 1]
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")
    with pytest.raises(RuntimeError, match="no GPU visible"):
        gpu_cluster()


def test_torch_tensors_on_the_device_path(cpu, frames, device_path, monkeypatch, torch):
    """Tensors with the working arrays in Taichi ndarrays (as on CUDA): the
    frame is computed in the output tensor, no host copy of it is made."""
    truth, mask = frames
    with engine.device_buffers(False):
        want = ipc_taichi.decouple(truth, mask=mask)
    copies = []
    upload = engine.HostCopies.upload
    monkeypatch.setattr(engine.HostCopies, "upload",
                        lambda self, nd, host: (copies.append(host.shape) if host.size > 4
                                                else upload(self, nd, host)))
    got = ipc_taichi.decouple(torch.from_numpy(truth), mask=torch.from_numpy(mask))
    assert isinstance(got, torch.Tensor) and same(got, want) and copies == []
    ws = engine.cached_workspaces()[-1]  # the one used last
    assert ws.device_buffers and not isinstance(ws.prev, np.ndarray)


def test_host_load_matches_the_load_kernel(cpu, frames, device_path):
    """On the CPU, NumPy loads the frame (faster than Taichi's scalar loop); the
    device path uses the load kernel: bit-identical results for inf, NaN, mask,
    the isolated edge, another dtype, a strided view, and frames with and
    without bad pixels in turn (the reused ``ok`` array must be reset)."""
    truth, mask = frames
    measured = np.stack([couple_reference(f) for f in np.nan_to_num(truth)])
    measured[0, 5, 6] = np.inf
    measured[2, 30, 3] = np.nan
    inputs = [measured, measured.astype(np.float32), measured[:, ::-1, :]]
    results = {}
    for forced in (False, True):
        engine.clear_workspaces()
        with engine.device_buffers(forced):
            results[forced] = [(ipc_taichi.decouple(m, mask=mask, full_output=True),
                                ipc_taichi.couple(m, edge="isolated"),
                                ipc_taichi.couple(m, edge="isolated", mask=mask[::-1])[1],
                                ipc_taichi.couple(m[1], edge="isolated")) for m in inputs]
    for host, device in zip(results[False], results[True]):
        (want, want_info), *want_rest = host
        (got, info), *got_rest = device
        assert same(got, want) and [i.max_delta for i in info] == [
            i.max_delta for i in want_info]
        assert all(same(a, b) for a, b in zip(got_rest, want_rest))
    (first, _), stack_isolated, _, alone = results[False][0]
    assert np.isnan(first[0, 5, 6]) and first[0, 20, 11] == measured[0, 20, 11]
    assert same(stack_isolated[1], alone)  # frame 1 after a frame with bad pixels
    assert np.array_equal(alone, couple_reference(measured[1], edge="isolated")) or \
        np.abs(alone - couple_reference(measured[1], edge="isolated")).max() <= 1e-10 * 6e4


@pytest.mark.parametrize("forced", [False, True])
def test_fresh_workspace_isolated_edge(cpu, rng, forced):
    """A new workspace's ``ok`` array lets every pixel couple (border: edge rule)."""
    engine.clear_workspaces()
    truth = rng.uniform(0, 60000, (23, 19))
    with engine.device_buffers(forced):
        got = ipc_taichi.couple(truth, edge="isolated")
    assert np.abs(got - couple_reference(truth, edge="isolated")).max() <= 1e-10 * 6e4
    engine.clear_workspaces()


class _MemDriver:
    """A stand-in CudaDriver whose device memory is host memory (copies by memmove)."""

    def __init__(self):
        self.buffers, self.copies = [], []

    def is_pinned(self, address):
        return False

    def host_alloc(self, nbytes):
        buffer = ctypes.create_string_buffer(nbytes)
        self.buffers.append(buffer)
        return ctypes.addressof(buffer)

    def free_host(self, address):
        pass

    def upload(self, device, host, nbytes):
        self.copies.append(("up", nbytes))
        ctypes.memmove(device, host, nbytes)

    def download(self, host, device, nbytes):
        self.copies.append(("down", nbytes))
        ctypes.memmove(host, device, nbytes)


def test_staged_copies_cover_the_frame_in_chunks(cpu, rng):
    """A large pageable frame crosses in STAGE_CHUNK chunks through one staging
    frame, by the copy threads; small frames and the pageable policy directly."""
    import taichi as ti

    frame = rng.uniform(0, 6e4, (700, 1100))  # 6.2 MB: 3 chunks and a part
    assert frame.nbytes >= engine.PIN_MIN_BYTES
    driver = _MemDriver()
    copies = engine.HostCopies("cuda", driver=driver)
    nd = ti.ndarray(ti.f64, frame.shape)
    copies.upload(nd, frame)
    assert np.array_equal(nd.to_numpy(), frame)
    chunks = -(-frame.nbytes // engine.STAGE_CHUNK)
    assert sorted(driver.copies) == sorted([("up", engine.STAGE_CHUNK)] * (chunks - 1)
                                           + [("up", frame.nbytes % engine.STAGE_CHUNK)])
    back = np.empty_like(frame)
    copies.download(back, nd)
    assert np.array_equal(back, frame) and len(driver.buffers) == 1  # one staging frame
    driver.copies.clear()
    with engine.pageable_copies():
        copies.download(back, nd)
    small = np.empty((10, 10))
    copies.upload(ti.ndarray(ti.f64, small.shape), small)
    assert driver.copies == [("down", frame.nbytes), ("up", small.nbytes)]
