"""The benchmark: its NumPy peer is right, and a tiny run writes both result files."""

import json

import numpy as np
import pytest

from ipc_taichi.bench import render_markdown, run_benchmark
from ipc_taichi.datasets import star_field
from ipc_taichi.reference import couple_reference, decouple_numpy, decouple_reference
from tests.helpers import optional


def test_numpy_peer_matches_reference(rng):
    for truth in (rng.uniform(0, 60000, (40, 33)), star_field(48, seed=1, n_per_mpix=5000)):
        measured = couple_reference(truth)
        ours, iterations, converged = decouple_numpy(measured)
        ref, ref_iterations, ref_converged, _ = decouple_reference(measured)
        assert (iterations, converged) == (ref_iterations, ref_converged)
        np.testing.assert_allclose(ours, ref, rtol=1e-11, atol=1e-9)
        assert np.abs(ours - truth).max() < 0.05


def test_star_field_is_seeded():
    a, b = star_field(64, seed=4), star_field(64, seed=4)
    assert np.array_equal(a, b) and a.max() > 300 and a.min() >= 100


def test_tiny_run_writes_results(tmp_path):
    from ipc_taichi.bench import write_results

    results = run_benchmark(sizes=(256,), kinds=("uniform",), repeats=2,
                            configs=["numpy", "taichi-cpu-f64"], progress=lambda s: None,
                            measure=False)
    rows = {r["config"]: r for r in results["rows"]}
    assert set(rows) == {"numpy", "taichi-cpu-f64"}
    for r in rows.values():
        assert r["repeats"] == 2 and len(r["times_s"]) == 2 and r["max_error"] < 0.05
        assert r["iterations"] == rows["numpy"]["iterations"]
    # NumPy's full-frame temporaries (several frames of 512 KiB, above malloc's mmap
    # threshold) show in the peak RSS. Taichi's working arrays, and even the measured
    # frame, may come from memory the process already holds resident (seen on a 2-core
    # AMD EPYC VM: the frame's 512 KiB read after the base RSS grew it by 0): the
    # Taichi row's RSS growth is a lower bound only, never negative.
    assert rows["numpy"]["peak_bytes"] >= 2 * rows["numpy"]["frame_bytes"]
    assert rows["taichi-cpu-f64"]["peak_bytes"] >= 0
    assert isinstance(rows["taichi-cpu-f64"]["peak_exact"], bool)
    # the first call compiles the kernels (seconds), a warm call on 256x256 takes milliseconds
    taichi = rows["taichi-cpu-f64"]
    assert taichi["first_call_s"] > 5 * taichi["warm_call_s"] > 0
    assert taichi["compile_s"] == taichi["first_call_s"] - taichi["warm_call_s"]
    assert rows["numpy"]["speedup_vs_numpy"] == 1.0
    write_results(results, tmp_path)
    again = json.loads((tmp_path / "results.json").read_text())
    assert again["rows"][0]["config"] == "numpy"
    text = (tmp_path / "RESULTS.md").read_text()
    assert "taichi-cpu-f64" in text and again["machine"]["cpu"] in text
    assert render_markdown(results) == text


def test_floor_measurement_is_positive_and_rendered(cpu):
    from ipc_taichi import runtime
    from ipc_taichi.bench import floor_model, machine, measure_floor

    try:
        measured = measure_floor(n=1 << 12, repeats=1)
    finally:
        runtime.init("cpu", "f64")  # it leaves Taichi in f32
    assert set(measured) == {"numpy_pair_ns", "pair_ns_f64", "stream_ns_f64", "pair_ns_f32",
                             "stream_ns_f32"}
    assert all(0 < v < 1e4 for v in measured.values())
    floor = dict(floor_model(None), measured=measured)
    row = {"config": "taichi-cpu-f64", "size": 64, "kind": "uniform", "median_s": 1e-3,
           "iterations": 4, "converged": True, "max_error": 0.01, "peak_bytes": 1,
           "frame_bytes": 64 * 64 * 8, "repeats": 1}
    text = render_markdown({"machine": machine(), "repeats": 1, "notes": [], "rows": [row],
                            "floor": floor})
    assert "the cost of its alphas alone" in text and "H100, 4096x4096 f64" in text


def test_cuda_section_runs_on_cpu_stand_in(cpu, torch):
    """The CUDA rows' code, run with PyTorch CPU tensors as the device: every
    row is timed and right, and the section renders (without verdicts: no GPU)."""
    from ipc_taichi import runtime
    from ipc_taichi.bench import measure_cuda, render_cuda

    try:
        cuda = measure_cuda(size=40, repeats=1, stack=3, arch="cpu")
    finally:
        runtime.init("cpu", "f64")  # it leaves Taichi in f32
    rows = {(r["row"], r["precision"]): r for r in cuda["rows"]}
    for prec in ("f64", "f32"):
        for name in ("host in/out (NumPy)", "host in/out, pinned buffers",
                     "host in/out, pageable copies", "device-resident (torch)",
                     "3-frame stack, host in/out, per frame"):
            r = rows[(name, prec)]
            assert r["median_ms"] > 0 and r["iterations"] >= 3 and r["max_error"] < 0.05, name
        assert rows[("3-frame stack, host in/out, per frame", prec)]["frames"] == 3
        for name in ("floor: alpha arithmetic alone (4 alphas/pixel)",
                     "floor: device copy of the frame", "floor: plain step (4 alphas, no maxima)"):
            assert rows[(name, prec)]["median_ms"] > 0
        host = rows[("host in/out (NumPy)", prec)]
        # the CPU's lanes workspace: three padded frames (estimate, next, measured),
        # rows of 40 + 2 border pixels rounded up to whole 64-byte vectors (48 in both
        # precisions), 42 rows: 1.26x the frame's area at this size, 1.002x at 4096
        padding = 42 * 48 / 40 ** 2
        assert host["workspace_bytes"] <= 3.5 * padding * host["frame_bytes"]
    assert any("CuPy" in n for n in cuda["notes"])
    text = render_cuda(cuda)
    assert "device-resident (torch)" in text and "ms: met" not in text and "NOT met" not in text


def test_without_gpu_the_cuda_section_is_noted(monkeypatch):
    import ipc_taichi.bench.launch
    bench = ipc_taichi.bench

    monkeypatch.setattr(bench.launch, "cuda_present", lambda: False)
    results = run_benchmark(sizes=(16,), kinds=("uniform",), repeats=1, configs=["numpy"],
                            progress=lambda s: None, measure=False)
    assert results["cuda"] is None
    assert any("CUDA section" in n and "not run" in n for n in results["notes"])
    assert "## CUDA" not in render_markdown(results)


def test_cuda_verdicts_rendered_for_the_must_show_frame():
    from ipc_taichi.bench import render_cuda

    def row(name, prec, ms, **extra):
        return dict(row=name, precision=prec, size=4096, frames=1, median_ms=ms, best_ms=ms,
                    iterations=4, max_error=0.03, **extra)

    cuda = {"arch": "cuda", "device": "test GPU", "notes": [], "rows": [
        row("device-resident (torch)", "f64", 2.5), row("CuPy peer, device-resident", "f64", 3.4),
        row("host in/out (NumPy)", "f64", 25.0, workspace_bytes=3, frame_bytes=1),
        row("upload one frame (pinned)", "f64", 3.0),
        row("download one frame (pinned)", "f64", 3.0),
        row("16-frame stack, host in/out, per frame", "f64", 9.0)]}
    text = render_cuda(cuda)
    assert "<= 3.0 ms: met" in text and "<= 20.0 ms: NOT met" in text
    assert "not slower" in text and "1.06x (target <= 1.2x)" in text
    assert "3.00x the frame's bytes" in text


def test_jwst_ipc_kernel_inverts_the_coupling():
    from ipc_taichi.bench.pipeline import jwst_ipc_kernel

    k = jwst_ipc_kernel(0.0125)
    assert k.shape == (3, 3) and abs(k.sum() - 1) < 1e-12
    assert k[1, 1] > 1.05 and abs(k[0, 1] + 0.0125) < 0.002 and abs(k[0, 0]) < 0.001
    couple = np.array([[0, 0.0125, 0], [0.0125, 0.95, 0.0125], [0, 0.0125, 0]])
    from scipy.signal import convolve2d

    both = convolve2d(couple, k)  # coupling then the pre-inverted kernel: near identity
    assert abs(both[2, 2] - 1) < 1e-3 and np.abs(both).sum() - 1 < 0.01


def test_row_beside_the_jwst_ipc_step(cpu):
    """Both methods on the same small ramp, in this process: the exact
    decoupler is far closer to the truth than the one-pass 3x3 kernel."""
    from ipc_taichi import runtime
    from ipc_taichi.bench import measure_pipeline_ipc, render_pipeline

    pytest.importorskip("jwst", reason=optional("jwst"))  # the row beside jwst's own ipc step
    try:
        # the law rows for one width, 4 f32 lanes (small kernels to compile)
        result = measure_pipeline_ipc(size=64, nints=1, ngroups=2, repeats=1, units=["4"],
                                      general_size=64)
    finally:
        runtime.init("cpu", "f64")  # it leaves Taichi in f32
    step, f64, f32 = result["rows"]
    assert "f64" in f64["row"] and "f32" in f32["row"]
    assert result["ratio"] == f64["vs_jwst"] == f64["median_s"] / step["median_s"]
    for ours in (f64, f32):
        assert step["median_s"] > 0 and ours["median_s"] > 0
        assert ours["vs_jwst_cpu"] > 0 and ours["threads"] >= 1
        assert ours["iterations"] and max(ours["iterations"]) <= 20
        assert 0 < ours["max_error"] < step["max_error"] / 5
    text = render_pipeline(result)
    assert "jwst ipc step" in text and f"{f32['vs_jwst']:.2f}x" in text
    # the CPU recorded; the law rows and the per-iteration rows at the unit asked for
    assert result["cpu"]["model"] and "CPU: " in text
    assert list(result["by_unit"]) == ["4"]
    laws = result["by_unit"]["4"]["law_rows"]
    assert [r["law"] for r in laws] == ["constant:0.0125", "donlon2018", "donlon2018",
                                        "table 257x257", "table 257x257"]
    assert all(r["row"].endswith(", 4 lanes)") and r["row"] in text for r in laws)
    general = result["general"]["laws"]
    assert [r["law"] for r in general] == ["constant:0.0125", "donlon2018", "table 257x257"]
    assert general[0]["law's cost [ns/pixel]"] == 0 and all(r["x floor"] > 0 for r in general)
    assert "the law's evaluation against the stream" in text


def test_cli_refuses_a_tiny_jwst_ramp(cli, tmp_path):
    result = cli("bench", "--jwst-size", "8", "--output", tmp_path)
    assert result.returncode != 0 and "--jwst-size" in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # a calibration on flat ramps: 10 s
def test_calibrate_row_is_measured_and_rendered():
    from ipc_taichi.bench.launch import work
    from ipc_taichi.bench.render import render_section

    section = work({"config": "calibrate", "size": 512, "groups": 3, "flat_size": 128,
                    "flat_ints": 2, "flat_groups": 5})
    row = section["rows"][0]
    assert row["hot pixels found"] > 10
    assert abs(row["alpha_x at 10 ke- (made with 0.006)"] - 0.006) < 0.0015
    assert row["BF / NL-IPC detected (none made)"] == "False / False"
    text = render_section(section)
    assert "512x512 x 3 groups" in text and "2 x 5 x 128x128" in text
