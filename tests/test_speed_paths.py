"""Issue 28's speed paths, checked for what they must keep true (never timed here):
a chosen precision sticks, Dask workers share the cores, and warm starts up a
ramp give the from-scratch answer to the stopping rule's tolerance in fewer
iterations."""

import os

import numpy as np
import pytest

import ipc_taichi
from ipc_taichi import engine, iteration, runtime
from ipc_taichi.cluster import worker_threads
from ipc_taichi.datasets import star_field

pytestmark = pytest.mark.filterwarnings(
    # distributed's own shutdown/port noise, not ours to fix
    "ignore::ResourceWarning", "ignore:Port 8787:UserWarning",
    "ignore:.*clean up.*:UserWarning")


# --------------------------------------------------------------------------- precision


def test_init_f32_sticks_for_the_next_decouple(cpu, monkeypatch, worked_truth):
    measured64 = ipc_taichi.couple(worked_truth)
    exact = ipc_taichi.decouple(measured64)
    try:
        chosen = ipc_taichi.init(precision="f32")
        # the environment chose the first runtime only; it no longer overrides
        monkeypatch.setenv(runtime.PRECISION_ENV, "f64")
        got = ipc_taichi.decouple(measured64)
        assert runtime.current() is chosen  # no re-initialisation, no recompile
        assert chosen.precision == "f32" and got.dtype == np.float32
        # f32 accuracy: relative rounding of a few 1e-7 of the signal
        np.testing.assert_allclose(got, exact, rtol=2e-6, atol=1e-2)
        assert ipc_taichi.couple(worked_truth).dtype == np.float32
        # an explicit precision still switches, and that sticks too
        assert ipc_taichi.decouple(measured64, precision="f64").dtype == np.float64
        assert ipc_taichi.decouple(measured64).dtype == np.float64
    finally:
        ipc_taichi.init("cpu", "f64")
    assert runtime.current().precision == "f64"


# --------------------------------------------------------------------------- threads


@pytest.mark.parametrize("workers, cores, threads", [(2, 2, 1), (2, 16, 8), (3, 16, 5),
                                                     (4, 2, 1), (1, 2, 2)])
def test_worker_threads_add_up_to_the_cores(workers, cores, threads):
    assert worker_threads(workers, cores) == threads
    assert workers * threads <= max(cores, workers)


def test_thread_cap_reaches_taichi(cpu, monkeypatch):
    import taichi as ti

    monkeypatch.setenv(runtime.THREADS_ENV, "1")
    try:
        info = ipc_taichi.init("cpu", "f32")  # a new runtime reads the cap
        assert info.threads == 1
        assert ti.lang.impl.current_cfg().cpu_max_num_threads == 1
    finally:
        monkeypatch.delenv(runtime.THREADS_ENV)
        ipc_taichi.init("cpu", "f64")
    assert runtime.current().threads is None
    monkeypatch.setenv(runtime.THREADS_ENV, "0")
    with pytest.raises(ValueError, match="positive integer"):
        runtime.cpu_threads()


def _worker_runtime():
    import taichi as ti

    info = runtime.init("cpu", "f64")
    return (os.environ.get(runtime.THREADS_ENV), info.threads,
            ti.lang.impl.current_cfg().cpu_max_num_threads)


def test_two_dask_workers_get_their_share_of_the_cores(monkeypatch):
    from ipc_taichi.cluster import close_client, local_client

    monkeypatch.delenv(runtime.THREADS_ENV, raising=False)
    client = local_client(workers=2)
    try:
        seen = client.run(_worker_runtime)
    finally:
        close_client(client)
    share = worker_threads(2)
    assert len(seen) == 2
    assert all(got == (str(share), share, share) for got in seen.values())


# --------------------------------------------------------------------------- warm starts


def _ramp(groups, size=96, law="donlon2018", seed=3):
    """``(truth, measured)``: a star field accumulating group by group, coupled."""
    rate = star_field(size, seed=seed) / groups + 40.0
    truth = np.stack([rate * (g + 1) for g in range(groups)])
    return truth, ipc_taichi.couple(truth, law=law)


def _within_stopping_tolerance(a, b):
    """Each frame of ``a`` and ``b`` agrees to the stopping rule's ``tol * max|S|``."""
    for fa, fb in zip(a, b):
        scale = iteration.TOL * np.nanmax(np.abs(fb))
        assert np.nanmax(np.abs(fa - fb)) <= scale


@pytest.mark.parametrize("law", ["donlon2018", "constant:0.0125"])
def test_warm_ramp_same_answer_fewer_iterations(cpu, law):
    truth, measured = _ramp(8, law=law)
    cold, cold_info = ipc_taichi.decouple(measured, law=law, full_output=True)
    warm, warm_info = ipc_taichi.decouple(measured, law=law, full_output=True, warm_start=True)
    assert [i.warm_start for i in warm_info] == [False] + [True] * 7
    assert all(i.converged for i in warm_info)
    _within_stopping_tolerance(warm, cold)
    # as close to the truth as from scratch, to the same tolerance
    err_cold = np.abs(cold - truth).max()
    assert np.abs(warm - truth).max() <= err_cold + iteration.TOL * np.abs(truth).max()
    cold_n = sum(i.iterations for i in cold_info)
    warm_n = sum(i.iterations for i in warm_info)
    assert warm_n <= cold_n - 7  # at least one iteration saved per warm group
    assert warm_info[0].iterations == cold_info[0].iterations  # the first from scratch
    if law.startswith("constant"):  # a linear law on a noise-free ramp: exact extrapolation
        assert [i.iterations for i in warm_info[2:]] == [1] * 6


def test_warm_unrelated_frames_still_correct(cpu, rng):
    truth = rng.uniform(0, 60000, (4, 40, 48))
    measured = ipc_taichi.couple(truth)
    cold = ipc_taichi.decouple(measured)
    warm, infos = ipc_taichi.decouple(measured, full_output=True, warm_start=True)
    assert all(i.converged for i in infos)
    _within_stopping_tolerance(warm, cold)
    assert np.abs(warm - truth).max() < 0.1


def test_warm_with_bad_pixels_and_in_place(cpu):
    truth, measured = _ramp(5, size=40)
    measured[2, 10, 11] = np.nan  # bad in one group only
    mask = np.zeros(measured.shape, dtype=bool)
    mask[1:, 20, 5] = True  # masked from the second group on
    cold = ipc_taichi.decouple(measured, mask=mask)
    inplace = measured.copy()
    warm = ipc_taichi.decouple(inplace, mask=mask, warm_start=True, out=inplace)
    assert warm is inplace
    assert np.isnan(warm[2, 10, 11]) and np.isfinite(warm[[0, 1, 3, 4], 10, 11]).all()
    np.testing.assert_array_equal(warm[1:, 20, 5], measured[1:, 20, 5])
    _within_stopping_tolerance(warm, cold)


def test_warm_device_kernels_agree_with_host(cpu):
    _, measured = _ramp(4, size=48)
    host, host_info = ipc_taichi.decouple(measured, full_output=True, warm_start=True)
    with engine.device_buffers():
        dev, dev_info = ipc_taichi.decouple(measured, full_output=True, warm_start=True)
    assert [i.iterations for i in dev_info] == [i.iterations for i in host_info]
    np.testing.assert_allclose(dev, host, rtol=1e-12, atol=1e-9)


def test_warm_start_leaves_a_single_frame_alone(cpu):
    _, measured = _ramp(2, size=32)
    one = ipc_taichi.decouple(measured[1])
    np.testing.assert_array_equal(ipc_taichi.decouple(measured[1], warm_start=True), one)
    # and a stack without it is each frame from scratch, bit for bit
    np.testing.assert_array_equal(ipc_taichi.decouple(measured)[1], one)


def test_ramp_bench_row_small(cpu):
    from ipc_taichi.bench.launch import work
    from ipc_taichi.bench.render import render_section

    try:
        section = work({"config": "ramp", "size": 96, "groups": 8, "repeats": 1})
    finally:
        ipc_taichi.init("cpu", "f64")  # it leaves Taichi in f32
    assert section["within_tolerance"]
    rows = section["rows"]
    assert [(r["law"], r["start"]) for r in rows] == [
        ("donlon2018", "from scratch"), ("donlon2018", "warm start"),
        ("constant:0.0125", "from scratch"), ("constant:0.0125", "warm start")]
    for scratch, warm in (rows[:2], rows[2:]):
        assert scratch["converged"] and warm["converged"]
        assert warm["max diff vs scratch [e-]"] <= warm["tol x max(S) [e-]"]
        total = [int(r["iterations"].split()[0]) for r in (scratch, warm)]
        assert total[1] < total[0]
    text = render_section(section)
    assert "96x96 x 8 groups" in text and "| donlon2018 | warm start |" in text


# --------------------------------------------------------------------------- bench rows


def test_issue_28_rows_beside_the_jwst_step(cpu):
    """The f32 rows of every law (from scratch and warm-started), the step
    interleaved with them, the streaming floor and the general law against it:
    measured on a small ramp in this process and rendered."""
    pytest.importorskip("jwst")
    from ipc_taichi.bench import measure_pipeline_ipc, render_pipeline

    try:
        result = measure_pipeline_ipc(size=64, nints=1, ngroups=3, repeats=1, precisions=("f32",))
    finally:
        runtime.init("cpu", "f64")  # it leaves Taichi in f32
    rows = {(r["law"], r["warm_start"]): r for r in result["law_rows"]}
    assert sorted(rows) == [("constant:0.0125", True), ("donlon2018", False),
                            ("donlon2018", True), ("table 257x257", False),
                            ("table 257x257", True)]
    step_error = result["rows"][0]["max_error"]
    for r in result["law_rows"]:
        assert r["median_s"] > 0 and r["vs_jwst_interleaved"] > 0 and len(r["jwst_times_s"]) == 1
        assert 0 < r["max_error"] < step_error / 5  # each law decoupled by itself, exactly
        assert r["total_iterations"] >= 3  # one iteration at least per group
    constant_scratch = result["rows"][1]["total_iterations"]
    assert rows[("constant:0.0125", True)]["total_iterations"] < constant_scratch
    general = result["general"]
    assert general["size"] == 128 and general["floor_s"] > 0
    assert general["vs_floor"] == general["iteration_s"] / general["floor_s"]
    text = render_pipeline(result)
    assert "table 257x257 (cpu f32, warm start, " in text  # then the vector unit
    assert all(r["row"] in text for r in result["law_rows"])
    assert f"**{general['vs_floor']:.1f}x the streaming floor**" in text


# --------------------------------------------------------------------------- host load


def test_float32_frame_checked_before_conversion(cpu, rng):
    """An f64 run on float32 frames checks finiteness on the float32 frame: a
    frame whose float32 sum overflows (finite pixels near the float32 maximum)
    takes the per-pixel test and is decoupled like the same frame in float64;
    a NaN pixel is still found (NaN out, its neighbours decoupled with it zeroed)."""
    frame = rng.uniform(100.0, 3000.0, (3, 17, 19)).astype(np.float32)
    frame[0, 4, 5] = frame[0, 12, 14] = 3.0e38  # the float32 sum: inf
    with np.errstate(over="ignore"):
        assert not np.isfinite(frame[0].sum()) and np.isfinite(frame).all()
    frame[2, 8, 8] = np.nan
    got = ipc_taichi.decouple(frame, precision="f64", law="constant:0.0125")
    want = ipc_taichi.decouple(frame.astype(np.float64), precision="f64", law="constant:0.0125")
    assert got.dtype == np.float64 and np.isnan(got[2, 8, 8])
    np.testing.assert_array_equal(got, want)
    assert np.isfinite(np.delete(got[2].ravel(), 8 * 19 + 8)).all()
    half = rng.uniform(100.0, 3000.0, (17, 19)).astype(np.float16)  # its own sum overflows
    np.testing.assert_array_equal(ipc_taichi.decouple(half, precision="f64"),
                                  ipc_taichi.decouple(half.astype(np.float64), precision="f64"))
