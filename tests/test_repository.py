"""Properties of the repository as a whole."""

import pathlib
import subprocess

ROOT = pathlib.Path(__file__).resolve().parent.parent


def test_no_file_cites_a_file_outside_the_repository():
    """A user who clones the project can read everything it cites: the facts
    live in docs/, not in files beside the checkout."""
    outside = ("../" + "shared", "REFERENCE" + ".md", "DISCOVERY_FORMAT" + ".md",
               "STYLE" + ".md")
    try:
        listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                                check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):  # not a git checkout: every file
        listed = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file()
                  and ".venv" not in p.parts and ".git" not in p.parts]
    offenders = []
    for name in listed:
        path = ROOT / name
        if path.suffix in (".png", ".npz", ".fits", ".asdf", ".lock") or not path.is_file():
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        offenders += [f"{name}: {word}" for word in outside if word in text]
    assert offenders == []


def test_stopping_rule_written_once():
    """``max|dS| <= tol * max|S|`` is coded in ipc_taichi.iteration only (the
    NumPy reference writes it again on purpose, as an independent twin)."""
    coded = set()
    for path in (ROOT / "ipc_taichi").rglob("*.py"):
        for line in path.read_text().splitlines():
            code = line.split("#")[0].strip()
            if "<= tol *" in code and code.startswith(("if ", "elif ", "return ", "while ")):
                coded.add(str(path.relative_to(ROOT)))
    assert coded == {"ipc_taichi/iteration.py", "ipc_taichi/reference.py"}
