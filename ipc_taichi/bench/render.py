"""The benchmark's report: Markdown as a pure function of the results dict
(:func:`render_markdown`, and its sections)."""

__all__ = ["render_markdown", "render_cuda", "render_pipeline", "render_section",
           "floor_model", "MUST_SHOW"]

MUST_SHOW = {
    ("device-resident (torch)", "f64"): 3.0, ("device-resident (torch)", "f32"): 1.5,
    ("host in/out (NumPy)", "f64"): 20.0, ("host in/out (NumPy)", "f32"): 10.0,
}


def render_cuda(cuda):
    """The CUDA section of RESULTS.md."""
    if not cuda:
        return ""
    if not cuda["rows"]:
        return "## CUDA\n\nNo CUDA row was measured.\n" + "".join(
            f"- {n}\n" for n in cuda["notes"])
    lines = ["## CUDA", "", f"Device: {cuda['device']}. Frame {cuda['rows'][0]['size']} x "
             f"{cuda['rows'][0]['size']} uniform 0..60000, law donlon2018, nearest neighbours, "
             "the paper's stopping rule. Median and best of warm runs (synchronised).", "",
             "| what | precision | median [ms] | best [ms] | iterations | max error | target |",
             "|---|---|---:|---:|---:|---:|---|"]
    judged = cuda.get("arch") == "cuda" and cuda["rows"][0]["size"] == 4096
    for r in cuda["rows"]:
        target = MUST_SHOW.get((r["row"], r["precision"])) if judged else None
        verdict = "" if target is None else (
            f"<= {target} ms: {'met' if r['median_ms'] <= target else 'NOT met'}")
        it = r.get("iterations")
        err = r.get("max_error")
        lines.append(f"| {r['row']} | {r['precision']} | {r['median_ms']:.3f} | "
                     f"{r['best_ms']:.3f} | {'' if not it else it} | "
                     f"{'' if err is None or not it else f'{err:.3g}'} | {verdict} |")
    by = {(r["row"], r["precision"]): r for r in cuda["rows"]}
    for prec in ("f64", "f32"):
        dev = by.get(("device-resident (torch)", prec))
        peer = by.get(("CuPy peer, device-resident", prec))
        if dev and peer:
            lines.append(f"- {prec}: device-resident {dev['median_ms']:.2f} ms vs CuPy peer "
                         f"{peer['median_ms']:.2f} ms "
                         f"({'not slower' if dev['median_ms'] <= peer['median_ms'] else 'SLOWER'}"
                         ").")
        st = next((r for r in cuda["rows"] if r["precision"] == prec
                   and r["row"].endswith("stack, host in/out, per frame")), None)
        up, dn = by.get(("upload one frame (pinned)", prec)), by.get(
            ("download one frame (pinned)", prec))
        if st and up and dn and dev:
            one = up["median_ms"] + dn["median_ms"] + dev["median_ms"]
            lines.append(f"- {prec}: stack per frame {st['median_ms']:.2f} ms vs upload + "
                         f"download + device decouple of one frame {one:.2f} ms: "
                         f"{st['median_ms'] / one:.2f}x (target <= 1.2x).")
        host = by.get(("host in/out (NumPy)", prec))
        if host and "workspace_bytes" in host:
            extra = (", device memory used by the call "
                     f"{host['device_bytes'] / host['frame_bytes']:.2f}x"
                     if "device_bytes" in host else "")
            lines.append(f"- {prec}: working buffers "
                         f"{host['workspace_bytes'] / host['frame_bytes']:.2f}x "
                         f"the frame's bytes{extra} (target <= 3.5x).")
    lines += [""] + [f"- {n}" for n in cuda["notes"]]
    return "\n".join(lines) + "\n"


def floor_model(info):
    """Work per pixel and iteration of the nearest-neighbour Jacobi step."""
    return {
        "per_pixel_iteration": {
            "alpha_pairs": 2, "exp": 4, "sqrt": 2,
            "other_flops": 34,
            "bytes_f64": 24, "bytes_f32": 12,
            "note": "2 pair alphas (each 2 exp + 1 sqrt + 8 flops), 18 flops for the flow, "
                    "update and maxima; memory: read S_(q-1) and M, write S_q once each "
                    "(neighbour reads hit cache)",
        },
        "h100": {"fp64_tflops": 34.0, "fp32_tflops": 67.0, "hbm_tb_s": 3.35,
                 "pixel_layout_flops": 250,
                 "note": "vendor peak figures (SXM, non-tensor)"},
    }


def _fmt_bytes(n):
    return f"{n / 2**20:.0f} MiB"


def render_markdown(results):
    m = results["machine"]
    lines = [
        "# Decoupling benchmark (`make bench`)",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['ram_gib']} GiB RAM, {m['os']}; "
        f"Python {m['python']}, NumPy {m['numpy']}, Taichi {m['taichi']}, "
        f"ipc_taichi {m['ipc_taichi']}. Load average at start: "
        f"{', '.join(str(v) for v in m['load_average_at_start'])} "
        "(anything near or above the core count means other processes shared the CPU "
        "and the timings are inflated).",
        "",
        "Law donlon2018, nearest neighbours, zero edge, the paper's stopping rule. Median of "
        f"{results['repeats']} warm runs per row (JIT compile time separate). `numpy` is the "
        "fastest plain-NumPy implementation we could write (pair-symmetric, in place, "
        "single-threaded); `numpy-reference` is the paper-faithful reference of the tests. "
        "Speed-up is relative to `numpy` on the same frame. Peak memory: growth of the "
        "process's peak RSS over its RSS before the frame was loaded (input frame included), "
        "also as a multiple of the frame's f64 bytes.",
        "",
        "| size | frame | implementation | median [s] | JIT [s] | iterations | max error vs truth "
        "| peak memory | x frame | speed-up vs numpy |",
        "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results["rows"]:
        if "error" in r:
            lines.append(f"| {r['size']} | {r['kind']} | {r['config']} | failed: {r['error']} "
                         "| | | | | | |")
            continue
        compile_s = f"{r['compile_s']:.2f}" if "compile_s" in r else "-"
        lines.append(
            f"| {r['size']} | {r['kind']} | {r['config']} | {r['median_s']:.3f} | {compile_s} | "
            f"{r['iterations']}{'' if r['converged'] else ' (not converged)'} | "
            f"{r['max_error']:.3g} | {_fmt_bytes(r['peak_bytes'])} | "
            f"{r['peak_bytes'] / r['frame_bytes']:.1f} | "
            f"{r.get('speedup_vs_numpy', float('nan')):.1f}x |")
    lines += ["", "Notes:", ""] + [f"- {n}" for n in results["notes"]]
    lines += ["", _floor_text(results), ""]
    for section in (render_pipeline(results.get("pipeline")), render_section(results.get("ramp")),
                    render_section(results.get("calibrate")),
                    render_section(results.get("bondmap")), render_cuda(results.get("cuda")),
                    render_section(results.get("cliramp")), render_section(results.get("startup")),
                    render_section(results.get("discover_ramps"))):
        if section:
            lines += [section]
    return "\n".join(lines)


def render_section(section):
    """A section measured elsewhere (e.g. the calibrate row: ``{"title": ...,
    "rows": [{column: value}], "notes": [...]}``) as a Markdown table."""
    if not section or not section.get("rows"):
        return ""
    columns = list(section["rows"][0])
    lines = [f"## {section['title']}", "", "| " + " | ".join(columns) + " |",
             "|" + "---|" * len(columns)]
    for row in section["rows"]:
        cells = (f"{v:.4g}" if isinstance(v, float) else str(v) for v in
                 (row.get(c, "") for c in columns))
        lines.append("| " + " | ".join(cells) + " |")
    lines += [""] + [f"- {n}" for n in section.get("notes", [])]
    return "\n".join(lines) + "\n"


def _floor_text(results):
    """The floor: work per pixel and iteration, measured building blocks, and
    how close each timed path gets (at the largest size)."""
    rows = [r for r in results["rows"] if "median_s" in r]
    floor = results["floor"]
    fm = floor["per_pixel_iteration"]
    cores = results["machine"]["cores"]
    out = ["## The floor", "",
           f"Per pixel and Jacobi iteration (nearest neighbours, pair-symmetric): "
           f"{fm['alpha_pairs']} alpha evaluations = {fm['exp']} exp + {fm['sqrt']} sqrt + "
           f"about {fm['other_flops']} other flops; memory traffic {fm['bytes_f64']} bytes "
           f"(f64) / {fm['bytes_f32']} bytes (f32): {fm['note']}.", ""]
    measured = floor.get("measured")
    bound = {}
    if measured:
        for prec in ("f64", "f32"):
            pair, stream = measured[f"pair_ns_{prec}"], measured[f"stream_ns_{prec}"]
            bound[prec] = max(fm["alpha_pairs"] * pair, stream)
            out.append(f"- This CPU, {prec}, measured on all {cores} cores: one pair alpha "
                       f"{pair:.2f} ns, streaming one pixel's bytes {stream:.2f} ns; the "
                       f"alphas alone cost **{bound[prec]:.1f} ns per pixel and iteration** "
                       f"in scalar code (one alpha at a time, as the `sweep` layout; the "
                       f"CPU's default `lanes` layout evaluates 16 (f32) or 8 (f64) at once "
                       f"on AVX2 and AVX-512, 8 or 4 on SSE and NEON).")
        out.append(f"- NumPy (one thread, SIMD exp where it has it): one pair alpha "
                   f"{measured['numpy_pair_ns']:.2f} ns.")
    h = floor["h100"]
    for prec, tflops in (("f64", h["fp64_tflops"]), ("f32", h["fp32_tflops"])):
        nbytes = fm[f"bytes_{prec}"]
        mem_ms = nbytes * 4096 ** 2 / (h["hbm_tb_s"] * 1e12) * 1e3
        flops = h["pixel_layout_flops"] * 4096 ** 2
        cmp_ms = flops / (tflops * 1e12) * 1e3
        out.append(f"- H100, 4096x4096 {prec} (vendor peaks, not measured): memory "
                   f"{mem_ms:.3f} ms + compute {cmp_ms:.3f} ms per iteration (the `pixel` "
                   f"layout evaluates 4 alphas per pixel, about {h['pixel_layout_flops']} "
                   f"flops), i.e. about {5 * max(mem_ms, cmp_ms):.1f} ms for 5 iterations.")
    out += ["", "How close each path gets (largest size, wall time per pixel and iteration; the "
                "streaming floor: the time to stream one pixel's bytes, measured above):", ""]
    for r in rows:
        if r["size"] == max(x["size"] for x in rows):
            per = r["median_s"] / (r["iterations"] * r["size"] ** 2) * 1e9
            prec = "f32" if r["config"].endswith("f32") else "f64"
            ratio = (f", {per / bound[prec]:.2f}x the cost of its alphas alone in scalar code, "
                     f"{per / measured[f'stream_ns_{prec}']:.1f}x the streaming floor"
                     if r["config"].startswith("taichi-cpu") and prec in bound else "")
            out.append(f"- {r['config']} {r['kind']} {r['size']}: {per:.1f} ns{ratio}.")
    out += ["", "See docs/performance.md for the discussion."]
    return "\n".join(out)


def render_pipeline(result):
    """Markdown for :func:`ipc_taichi.bench.pipeline.measure_pipeline_ipc`'s result."""
    if not result:
        return ""
    lines = ["## Beside the JWST pipeline's `ipc` step", "",
             f"{result['nints']} integrations x {result['ngroups']} groups of "
             f"{result['size']}x{result['size']} (NIRCam-like, 4 reference pixels each side), "
             f"constant alpha {result['alpha']:g}, in one process; compute only (median of "
             "warm runs). Issue 39's targets (f32, on AVX2 as well as on AVX-512): the exact "
             "decoupler (converged) at most 0.35x the step's time with the constant law, "
             "0.8x with `donlon2018` and with a 257x257 table law (issue 28's, before: 0.5x, "
             "1.0x, 1.0x; f64 constant 0.8x).", ""] + _cpu_lines(result) + [
             "| method | median [s] | x the jwst step | x the step, interleaved "
             "| x the step, CPU time / threads | max error [e-] | iterations |",
             "|---|---:|---:|---:|---:|---:|---|"]
    by_unit = result.get("by_unit") or {None: {"law_rows": result.get("law_rows", [])}}
    for r in result["rows"] + [r for u in by_unit.values() for r in u["law_rows"]]:
        its = ", ".join(str(i) for i in r.get("iterations", [])) or "1 pass"
        if "total_iterations" in r:
            its += f" ({r['total_iterations']} in all)"
        ratio = f"{r['vs_jwst']:.2f}x" if "vs_jwst" in r else ""
        mixed = f"{r['vs_jwst_interleaved']:.2f}x" if "vs_jwst_interleaved" in r else ""
        cpu = f"{r['vs_jwst_cpu']:.2f}x" if "vs_jwst_cpu" in r else ""
        lines.append(f"| {r['row']} | {r['median_s']:.3f} | {ratio} | {mixed} | {cpu} | "
                     f"{r['max_error']:.3g} | {its} |")
    lines += ["", "- x the jwst step: the median against the step's median timed first; "
              "interleaved: against the step timed before each run of the row (the ratio of "
              "the two medians; both see the same load on a shared machine); CPU time / "
              "threads: our CPU time over the threads it ran on against the step's (one "
              "thread), medians of the same runs: what an idle machine shows where the "
              "threads scale (under load two threads and one do not see the same machine)."]
    lines += _pipeline_floor(result)
    return "\n".join(lines) + "\n"


def _pipeline_floor(result):
    """The streaming floor measured beside the pipeline rows, and the general law
    per iteration against it (lines of Markdown; none for an older result)."""
    if "floor_s" not in result:
        return []
    size, floor = result["size"], result["floor_s"]
    lines = ["", f"- The machine's streaming floor, measured in the same process: one NumPy "
                 f"copy of a {size}x{size} f32 frame (read and write every pixel once) "
                 f"{floor * 1e3:.2f} ms; the JWST step takes "
                 f"{result['jwst_per_group_s'] / floor:.0f}x that per group."]
    by_unit = result.get("by_unit") or {None: {"general": result.get("general")}}
    for general in (u["general"] for u in by_unit.values() if u.get("general")):
        n = general["size"]
        lanes = f", `lanes` step for {general['lanes']}" if "lanes" in general else ""
        lines.append(f"- General law (`{general['law']}`), {n}x{n} {general['precision']}"
                     f"{lanes}, per Jacobi iteration: {general['iteration_s'] * 1e3:.1f} ms "
                     f"({general['ns_per_pixel']:.2f} ns per pixel), "
                     f"**{general['vs_floor']:.1f}x the streaming floor** (one NumPy copy of "
                     f"that frame, {general['floor_s'] * 1e3:.2f} ms, median of copies "
                     "between the runs; issue 39's target 2x, issue 28's 5x).")
    for general in (u["general"] for u in by_unit.values() if u.get("general")):
        if general.get("laws"):
            lines += ["", render_section({
                "title": f"Per iteration, {general['size']}x{general['size']} f32, "
                         f"`lanes` step for {general['lanes']}: the law's evaluation against "
                         "the stream",
                "rows": general["laws"],
                "notes": ["ipc_taichi.bench.pipeline._general: the same step with each law "
                          "(constant: no alpha evaluated), interleaved; per iteration = (5 "
                          "iterations - 1) / 4; x floor: against one NumPy copy of the frame; "
                          "the law's cost: the difference to the constant law per pixel."]})]
    return lines


def _cpu_lines(result):
    """The CPU the section ran on (lines of Markdown; none for an older result)."""
    cpu = result.get("cpu")
    if not cpu:
        return []
    return [f"CPU: {cpu['model']}; vector extensions {' '.join(cpu['vector_extensions'])}; "
            f"the `lanes` step built for {cpu['vector_unit'] or 'none (the sweep)'} unless a "
            "row names another width (forced by `IPC_TAICHI_LANES`: LLVM still compiles for "
            "this CPU). Load average when the section ended: "
            f"{', '.join(str(v) for v in cpu['load_average'])}.", ""]
