"""The engine's edge cases found by the review of the CUDA path, run on the
CPU: frames wider than the reduction tree, threads, the caller's PyTorch
stream, ``out=`` given as the input, and the tensor dtypes NumPy takes."""

import threading
from types import SimpleNamespace

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import engine
from tests.helpers import optional, same


@pytest.fixture
def bad_frames(rng):
    truth = rng.uniform(0, 60000, (2, 23, 19))
    truth[1, 4, 7] = np.nan
    truth[0, 9, 2] = np.inf
    mask = np.zeros((23, 19), bool)
    mask[11, 12] = True
    return truth, mask


def test_frames_wider_than_the_reduction_tree(cpu, rng):
    """With a tree of capacity 2**5 = 32 (instead of 32**5), a 20 x 40 frame
    leaves 40 partial maxima: the pixel layout's stopping-rule maxima must be
    those of the whole frame (the sweep layout's, to rounding), not of the
    first 32 columns (the largest signal is put in the last columns)."""
    signal = rng.uniform(0, 1000, (20, 40))
    signal[13, 38] = 60000.0
    measured = ipc_taichi.couple(signal)
    ref, ref_info = ipc_taichi.decouple(measured, layout="sweep", full_output=True)
    with engine.reduction_fan_in(2):
        assert engine.tree_rows(40) == 2
        got, info = ipc_taichi.decouple(measured, layout="pixel", full_output=True)
    assert engine.tree_rows(40) == 1
    assert info.iterations == ref_info.iterations
    np.testing.assert_allclose(info.max_signal, ref_info.max_signal, rtol=1e-12)
    np.testing.assert_allclose(info.max_delta, ref_info.max_delta, rtol=1e-9)
    assert info.max_signal[0] > 59000
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)


def test_threads_are_served_one_at_a_time(cpu, rng):
    """Two threads decoupling different frames at once share the engine's
    working arrays: the results are those of serial calls, bit for bit, and
    while one call runs (here: in its callback) no other thread enters."""
    frames = [ipc_taichi.couple(rng.uniform(0, 60000, (48, 40))) for _ in range(2)]
    serial = [ipc_taichi.decouple(f) for f in frames]
    results = [[], []]
    errors = []

    def work(i):
        try:
            for _ in range(4):
                results[i].append(ipc_taichi.decouple(frames[i]))
        except Exception as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    for i in range(2):
        assert len(results[i]) == 4 and all(same(r, serial[i]) for r in results[i])

    entered = []

    def callback(q, estimate):
        if q == 1:
            other = threading.Thread(target=lambda: entered.append(
                engine.ENGINE_LOCK.acquire(timeout=0.05)))
            other.start()
            other.join()

    ipc_taichi.decouple(frames[0], callback=callback)
    assert entered == [False]


class _Stream:
    def __init__(self, name, log):
        self.name, self.log = name, log

    def wait_stream(self, other):
        self.log.append(("wait", self.name, other.name))


class _FakeCuda:
    """A stand-in for ``torch.cuda`` that records what the engine orders."""

    def __init__(self, current):
        self.log = []
        self.default = _Stream("default", self.log)
        self.current = self.default if current == "default" else _Stream(current, self.log)

    def current_stream(self, device):
        return self.current

    def default_stream(self, device):
        return self.default

    def stream(self, s):
        log = self.log

        class Inside:
            def __enter__(self):
                log.append(("enter", s.name))

            def __exit__(self, *exc):
                log.append(("leave", s.name))

        return Inside()


class _CudaTensor:
    """A stand-in for a CUDA tensor (its device, and the streams it was marked used by)."""

    def __init__(self, device="cuda"):
        self.device = SimpleNamespace(type=device, index=0)
        self.recorded = []

    def record_stream(self, s):
        self.recorded.append(s.name)


def test_work_is_ordered_with_the_callers_stream():
    cuda = _FakeCuda("side")
    tensor, result = _CudaTensor(), _CudaTensor()
    with engine.torch_stream_order(tensor, cuda=cuda) as order:
        assert cuda.log == [("wait", "default", "side"), ("enter", "default")]
        order.adopt(result)
    assert cuda.log[2:] == [("leave", "default"), ("wait", "side", "default")]
    assert result.recorded == ["side"]
    # on the default stream, and for CPU tensors: nothing to order
    cuda = _FakeCuda("default")
    with engine.torch_stream_order(tensor, cuda=cuda) as order:
        order.adopt(result)
    assert cuda.log == [] and result.recorded == ["side"]
    with engine.torch_stream_order(_CudaTensor("cpu"), cuda=cuda) as order:
        order.adopt(result)
    assert cuda.log == [] and result.recorded == ["side"]


@pytest.fixture(params=["numpy", "torch", "device-path"])
def kind(request):
    if request.param == "torch":
        request.getfixturevalue("torch")  # skips without PyTorch
    engine.clear_workspaces()
    with engine.device_buffers(request.param == "device-path"):
        yield request.param
    engine.clear_workspaces()


@pytest.mark.parametrize("function", ["couple", "decouple"])
def test_out_given_as_the_input_keeps_bad_pixels(cpu, bad_frames, kind, function):
    torch = pytest.importorskip("torch", reason=optional("torch")) if kind == "torch" else None
    truth, mask = bad_frames
    run = getattr(ipc_taichi, function)
    expected = run(truth, mask=mask)
    data = truth.copy() if kind != "torch" else torch.from_numpy(truth.copy())
    got = run(data, mask=mask, out=data)
    assert got is data or np.shares_memory(np.asarray(got), np.asarray(data))
    assert same(got, expected)
    assert np.isnan(np.asarray(got)[0, 9, 2]) and np.isnan(np.asarray(got)[1, 4, 7])
    assert np.asarray(got)[0, 11, 12] == truth[0, 11, 12]  # masked: its input value
    # a view of the input as out= (one frame of the stack, given as a 2-D frame)
    frame = truth[1].copy() if kind != "torch" else torch.from_numpy(truth[1].copy())
    back = run(frame, mask=mask, out=frame)
    assert same(back, expected[1])


def test_out_overlapping_the_input_is_refused(cpu, bad_frames):
    truth, _ = bad_frames
    big = np.zeros((3,) + truth.shape[1:])
    big[:2] = truth
    before = big.copy()
    with pytest.raises(ipc_taichi.IPCInputError, match="overlaps the input"):
        ipc_taichi.decouple(big[:2], out=big[1:3])
    assert np.array_equal(big, before, equal_nan=True)


def test_uint16_tensors_are_taken_like_uint16_arrays(cpu, rng, torch):
    counts = rng.integers(0, 60000, (2, 21, 17)).astype(np.uint16)
    expected = ipc_taichi.decouple(counts)
    got = ipc_taichi.decouple(torch.from_numpy(counts))
    assert got.dtype == torch.float64 and same(got, expected)


def test_bfloat16_cpu_tensors_are_converted(cpu, rng, torch):
    signal = torch.from_numpy(rng.uniform(0, 60000, (21, 17))).to(torch.bfloat16)
    expected = ipc_taichi.decouple(signal.to(torch.float64).numpy())
    got = ipc_taichi.decouple(signal)
    assert got.dtype == torch.float64 and same(got, expected)
    coupled = ipc_taichi.couple(signal, mask=np.eye(21, 17, dtype=bool))
    assert same(coupled, ipc_taichi.couple(signal.to(torch.float64).numpy(),
                                            mask=np.eye(21, 17, dtype=bool)))
