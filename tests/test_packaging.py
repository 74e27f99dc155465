"""Issue 27 item 7: what the wheel installs.

The study package (the folder ``analysis/``) is installed as
``ipc_taichi_analysis``, so that it cannot clash with a user's own ``analysis``;
every package of ``ipc_taichi`` is in the wheel.
"""

import pathlib
import shutil
import subprocess
import sys
import tomllib
import zipfile

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
STUDY = "ipc_taichi_analysis"


def _library_packages():
    return {".".join(p.parent.relative_to(ROOT).parts)
            for p in (ROOT / "ipc_taichi").rglob("__init__.py")}


def test_every_package_is_named_and_the_study_is_renamed():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert set(config["packages"]) == _library_packages() | {STUDY}
    assert config["package-dir"] == {STUDY: "analysis"}
    assert "analysis" not in config["packages"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    """The wheel, built from a copy of the sources (no build files in the checkout)."""
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for folder in ("ipc_taichi", "analysis"):
        shutil.copytree(ROOT / folder, src / folder,
                        ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                        "--no-build-isolation", "--no-index", "-q", str(src), "-w", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    (path,) = out.glob("ipc_taichi-*.whl")
    return path


def test_the_wheel_installs_no_top_level_analysis(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert "analysis" not in tops
    assert {"ipc_taichi", STUDY} <= tops
    assert f"{STUDY}/psf.py" in names and f"{STUDY}/binary.py" in names
    for package in _library_packages():
        assert package.replace(".", "/") + "/__init__.py" in names


def test_the_installed_study_imports_under_its_name(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = ("import ipc_taichi_analysis.binary as b, ipc_taichi_analysis.psf as p\n"
            "print(b.__file__); print(p.__file__); print(b.source_hash())")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=tmp_path, env={"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin"},
                       timeout=300)
    assert r.returncode == 0, r.stderr
    binary, psf, digest = r.stdout.split()
    assert binary.startswith(str(site / STUDY)) and psf.startswith(str(site / STUDY))
    assert len(digest) == 16
