"""Properties of the repository as a whole."""

import ast
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


def _library_modules():
    """``{dotted module name: path}`` of every module of ``ipc_taichi``."""
    modules = {}
    for path in sorted((ROOT / "ipc_taichi").rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = path
    return modules


# Modules other work is splitting now (issue 21); each entry must still be over the
# limit, so the list can only shrink.
_OVER_600_BEING_SPLIT = set()


def test_library_modules_fit_in_a_head():
    """No library module over 600 lines."""
    lengths = {str(p.relative_to(ROOT)): len(p.read_text().splitlines())
               for p in _library_modules().values()}
    too_long = {name for name, n in lengths.items() if n > 600}
    assert too_long - _OVER_600_BEING_SPLIT == set()
    assert _OVER_600_BEING_SPLIT - too_long == set(), "split: take it off the list"


def _module_level_imports(name, path, modules):
    """The library modules that ``name`` imports when it is imported (imports
    inside functions left out)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name in modules}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            # ``from base import sub`` loads the submodule; any other name is
            # taken from ``base`` itself (its __init__ for a package)
            found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                      for a in node.names} & modules.keys()
    return found - {name}


def test_no_import_circle():
    """The library's modules import each other as a tree-like graph: no module
    reaches itself through module-level imports."""
    modules = _library_modules()
    graph = {name: _module_level_imports(name, path, modules) for name, path in modules.items()}
    circles = []

    def visit(name, trail):
        for nxt in graph[name]:
            if nxt in trail:
                circles.append(" -> ".join(trail[trail.index(nxt):] + [nxt]))
            elif nxt not in done:
                visit(nxt, trail + [nxt])
        done.add(name)

    done = set()
    for name in graph:
        if name not in done:
            visit(name, [name])
    assert circles == []
    # the check sees real imports: the package imports its exceptions (the rest on
    # first use), the forward model its model
    assert "ipc_taichi.errors" in graph["ipc_taichi"]
    assert "ipc_taichi.model" in graph["ipc_taichi.coupling"]


# Signatures in files other work owns now (issue 21) that still retype the paper's
# 20 and 1e-5; each must still do so, so the list can only shrink.
_RETYPED_ELSEWHERE = {"analysis/psf.py", "analysis/simulate.py"}


def test_the_papers_stopping_rule_defaults_are_written_once():
    """``max_iter=20`` and ``tol=1e-5`` are :data:`ipc_taichi.iteration.MAX_ITER`
    and :data:`~ipc_taichi.iteration.TOL`; signatures use those names."""
    retyped = set()
    for top in ("ipc_taichi", "analysis"):
        for path in (ROOT / top).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                args = node.args.args + node.args.kwonlyargs
                defaults = ([None] * (len(node.args.args) - len(node.args.defaults))
                            + node.args.defaults + node.args.kw_defaults)
                for arg, default in zip(args, defaults):
                    if isinstance(default, ast.Constant) and (arg.arg, default.value) in (
                            ("max_iter", 20), ("tol", 1e-5)):
                        retyped.add(str(path.relative_to(ROOT)))
    assert retyped - _RETYPED_ELSEWHERE == set()
    assert _RETYPED_ELSEWHERE - retyped == set(), "fixed: take it off the list"
