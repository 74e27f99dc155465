"""The docs' examples give what a user gets: each example below is run as the
docs write it (its code or command read from the markdown) and the numbers
the docs state are read from the same text, rounded as the docs round them,
so a doc edit that drifts from the code fails here.

Covered: README's quick start (the paper's worked example as ``make demo``
prints it), docs/analysis.md (its ``import analysis`` examples run as a user
imports as a user has them in a fresh checkout: a Python started in the
repository's root; the PSF, FWHM, zero-point and effective-PSF numbers) and docs/discover.md's first
example (``simulate-lab`` then ``discover``; slow)."""

import ast
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _read(name):
    return (ROOT / name).read_text()


def _found(pattern, text):
    """The groups of ``pattern`` in ``text`` (whitespace in the docs may wrap)."""
    match = re.search(pattern, text, re.S)
    assert match, f"the docs no longer say {pattern!r}"
    return match.groups()


def _block(text, heading, lang):
    """The first ``lang`` code block after the line ``heading``."""
    section = text.split(f"\n{heading}\n", 1)
    assert len(section) == 2, heading
    return _found(rf"```{lang}\n(.*?)```", section[1])[0]


def _fresh_python(code, cwd):
    """``python -c code`` in ``cwd`` as a user starts it: no PYTHONPATH."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


# ---- README ----------------------------------------------------------------------------


def test_readme_quick_start_worked_example(cpu):
    from ipc_taichi import couple, decouple
    from ipc_taichi.datasets import worked_example

    text = _read("README.md")
    peak, *after, stop = _found(r"coupled peak ([\d.]+),\s+then ([\d.]+), ([\d.]+), ([\d.]+) "
                                r"after\s+1-3 iterations, stopping after (\d+)", text)
    measured = couple(worked_example())
    assert f"{measured.max():.2f}" == peak
    peaks = []
    decouple(measured, max_iter=len(after), tol=0.0,
             callback=lambda q, estimate: peaks.append(f"{estimate.max():.2f}"))
    assert peaks == after
    assert decouple(measured, full_output=True)[1].iterations == int(stop)


# ---- docs/analysis.md ------------------------------------------------------------------


def test_analysis_imports_work_from_a_fresh_checkout(tmp_path):
    """Every import line of the docs' examples, in a Python started in the
    repository's root with no PYTHONPATH (as a fresh checkout has it); in
    another folder ``analysis`` is not importable, as the docs say."""
    text = _read("docs/analysis.md")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    imports = [line for block in blocks for line in block.splitlines()
               if re.match(r"(from|import) analysis\b", line)]
    assert len(imports) >= 3
    run = _fresh_python("\n".join(imports), ROOT)
    assert run.returncode == 0, run.stderr
    elsewhere = _fresh_python("import analysis", tmp_path)
    assert elsewhere.returncode != 0 and "No module named 'analysis'" in elsewhere.stderr


def test_analysis_psf_and_fwhm_numbers():
    from analysis.fwhm import fwhm_azimuthal, fwhm_gaussian_fit, fwhm_spline
    from analysis.psf import jwst_f405n_psf, optical_psf, point_source_image

    text = _read("docs/analysis.md")
    held, = _found(r"a 40x40 px field holding ([\d.]+) % of the light", text)
    ours, = _found(r"\(([\d.]+) px on ours, centred on a sample\)", text)
    half, = _found(r"its half maximum is ([\d.]+) px \(spline and azimuthal profile alike\)", text)
    central, = _found(r"pixel-integrated JWST-like PSF\s+\(which holds ([\d.]+) % of the light\)",
                      text)
    ny, nx = map(int, _found(r'optical_psf\("jwst_f405n"\)\s+# (\d+)x(\d+), 4x oversampled, '
                             r"sum 1, source on the middle sample", text))
    psf = optical_psf("jwst_f405n")
    assert psf.shape == (ny, nx) and round(float(psf.sum()), 12) == 1.0
    assert np.unravel_index(np.argmax(psf), psf.shape) == (ny // 2, nx // 2)
    _, fraction = jwst_f405n_psf()
    assert f"{100 * fraction:.1f}" == held
    assert f"{fwhm_gaussian_fit(psf, 4):.3f}" == ours
    spline = fwhm_spline(psf, 4)
    assert {f"{spline.x:.3f}", f"{spline.y:.3f}", f"{fwhm_azimuthal(psf, 4):.3f}"} == {half}
    image = point_source_image(psf, x=20, y=20, shape=(41, 41), flux=1.0)
    assert f"{100 * image[20, 20]:.2f}" == central


def test_analysis_airy_fwhm():
    from analysis.fwhm import fwhm_azimuthal
    from analysis.psf import JWST_DIAMETER, PIXEL_SCALE, WAVELENGTH, optical_psf

    text = _read("docs/analysis.md")
    said, = _found(r'optical_psf\("airy"\)\s+# Airy disk, same lambda/D \(D = 6.5 m\), FWHM '
                   r"([\d.]+) lambda/D", text)
    lambda_over_d = np.degrees(WAVELENGTH / JWST_DIAMETER) * 3600 / PIXEL_SCALE  # pixels
    assert f"{fwhm_azimuthal(optical_psf('airy'), 4) / lambda_over_d:.3f}" == said


def test_analysis_zero_point_counts():
    from analysis.simulate import ZERO_POINT, flux_from_mag

    text = _read("docs/analysis.md")
    zero, = _found(r"`ZERO_POINT = ([\d.]+)` mag for 1 count/s", text)
    mags = _found(r"\(([\d.]+)/([\d.]+)/([\d.]+) mag\) ([\d.e]+), ([\d.e]+) and ([\d.e]+) counts "
                  r"in 10 ks", text)
    assert float(zero) == ZERO_POINT
    for mag, counts in zip(mags[:3], mags[3:], strict=True):
        assert float(f"{flux_from_mag(float(mag), exptime=1e4):.3g}") == float(counts)


def test_analysis_effective_psf_sums_as_said(cpu):
    """The "Detector images and the effective PSF" block, run as written on
    the optical PSF of the block before it."""
    from analysis.psf import optical_psf

    text = _read("docs/analysis.md")
    block = _block(text, "## Detector images and the effective PSF", "python")
    total, = _found(r"epsf = effective_psf\(.*?\)\s+# sums to (\d+)", block)
    names = {"psf": optical_psf("jwst_f405n")}
    exec(block, names)  # noqa: S102 (the docs' own example)
    assert round(float(names["epsf"].sum()), 9) == int(total)
    assert names["image"].shape == (41, 41) and callable(names["surface"])


# ---- docs/discover.md ------------------------------------------------------------------


@pytest.mark.slow
def test_discover_first_example(cli, tmp_path, monkeypatch):
    """The two commands of the first example (``--figures`` left out: the
    figures change no number), the summary line and the report's fields the
    Python example states."""
    text = _read("docs/discover.md")
    block = _found(r"```sh\n(.*?)```", text)[0]
    commands = [shlex.split(line) for line in block.splitlines() if line.startswith("ipc-taichi")]
    said, = _found(r"\n# (complete: missing effects .*?)\n", block)
    monkeypatch.chdir(tmp_path)
    for words in commands:
        if "--figures" in words:
            at = words.index("--figures")
            del words[at:at + 2]
        r = cli(*words[1:])
        assert r.returncode == 0, r.stderr
    assert said in (r.stdout + r.stderr).splitlines()
    python = _found(r"```python\n(.*?)```", text)[0]
    missing, = _found(r'result.report\["missing_effects"\]\s+# (\[.*?\])', python)
    complete, = _found(r'result.report\["complete"\]\s+# (\w+)', python)
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["missing_effects"] == ast.literal_eval(missing)
    assert str(report["complete"]) == complete
