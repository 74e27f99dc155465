"""Properties of the repository as a whole."""

import ast
import pathlib
import re
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


# ----------------------------------------------------------------- the core's face

# The core: the private modules (``ipc_taichi/_*.py``) and the modules that face
# them. Nothing else imports a private module (the benchmark and the tests go
# through ipc_taichi.engine).
CORE_FACES = {"ipc_taichi.coupling", "ipc_taichi.decoupling", "ipc_taichi.engine"}


def _is_private(module):
    return module.startswith("ipc_taichi.") and any(
        part.startswith("_") and not part.startswith("__") for part in module.split("."))


def _python_files():
    """Every Python file of the checkout that git tracks (or, outside git, finds)."""
    try:
        listed = subprocess.run(["git", "ls-files", "*.py"], cwd=ROOT, capture_output=True,
                                text=True, check=True).stdout.split()
        paths = [ROOT / name for name in listed]
    except (OSError, subprocess.CalledProcessError):
        paths = [p for p in ROOT.rglob("*.py") if ".venv" not in p.parts and "build" not in p.parts]
    return [p for p in paths if p.is_file()]


def _module_name(path):
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path, where="anywhere"):
    """``[(line, module, in_function)]``: what ``path`` imports, relative imports
    resolved, ``from M import name`` given as ``M.name`` when that is a module
    of ipc_taichi, else ``M``."""
    modules = _library_modules()
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text())
    in_function = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            in_function |= {id(sub) for sub in ast.walk(node) if sub is not node}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                     for a in node.names]
        else:
            continue
        found += [(node.lineno, m, id(node) in in_function) for m in names]
    return found


def test_nothing_outside_the_core_imports_a_private_module():
    """No module outside the core (the private modules and :data:`CORE_FACES`)
    imports ``ipc_taichi._anything``: not the library, the tests, the analysis,
    the figures or the docs."""
    offenders = []
    for path in _python_files():
        importer = _module_name(path)
        if importer in CORE_FACES or _is_private(importer):
            continue
        offenders += [f"{path.relative_to(ROOT)}:{line}: {module}"
                      for line, module, _ in _imports(path) if _is_private(module)]
    assert offenders == []
    # the check sees real imports: the core does import its private modules
    core = _imports(ROOT / "ipc_taichi" / "engine.py")
    assert ("ipc_taichi._engine" in {m for _, m, _ in core})


def _underscore_names_taken(path):
    """``[(line, "module._name")]``: the underscore names (not dunders) that
    ``path`` takes from other library modules, by ``from M import _name`` or as
    ``alias._name`` of a module it imported (a ``_``-prefixed module itself, and
    its public names, are not underscore names)."""
    modules = _library_modules()
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text())
    bound, found = {}, []

    def underscore(n):
        return n.startswith("_") and not n.startswith("__")

    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            for a in node.names:
                if f"{base}.{a.name}" in modules:
                    bound[a.asname or a.name] = f"{base}.{a.name}"
                elif underscore(a.name) and base in modules:
                    found.append((node.lineno, f"{base}.{a.name}"))
        elif isinstance(node, ast.Import):
            bound.update({a.asname: a.name for a in node.names if a.asname and a.name in modules})
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) \
                and node.value.id in bound and underscore(node.attr):
            found.append((node.lineno, f"{bound[node.value.id]}.{node.attr}"))
    return found



def test_no_module_takes_another_modules_underscore_names():
    """A module's underscore names are its own: no module of the library imports
    another's (``from M import _x``, or ``M._x``), except inside the engine core,
    whose private modules (``ipc_taichi/_*.py``) share theirs. Any module may
    import a private module's public names."""
    taken, core = set(), set()
    for name, path in _library_modules().items():
        for _, where in _underscore_names_taken(path):
            owner = where.rpartition(".")[0]
            if owner == name:
                continue
            (core if _is_private(name) and _is_private(owner) else taken).add(
                f"{name} -> {where}")
    assert taken == set()
    # the check sees real imports: the core's modules do share underscore names
    assert "ipc_taichi._copies -> ipc_taichi._device._contiguous" in core


# Function-level imports of library modules, kept on purpose: the file (or folder)
# and why. Every other import of a library module is at the top of its module.
IMPORTED_WHEN_CALLED = {
    "ipc_taichi/cli/": "each subcommand imports its work when it runs, so `ipc-taichi "
                       "--help` and `decouple` do not load calibrate/ or discover/ "
                       "(0.4 s each, scipy and matplotlib)",
}


def test_library_imports_are_at_the_top_of_their_modules():
    """A library module imports its sibling modules at its top, where a reader
    sees what it depends on and the circle check sees it too; an import inside a
    function only where :data:`IMPORTED_WHEN_CALLED` says why. (Optional
    dependencies, e.g. torch or jwst, are not sibling modules: not checked here.)"""
    inside = {}
    for path in _library_modules().values():
        rel = str(path.relative_to(ROOT))
        if any(rel.startswith(kept) for kept in IMPORTED_WHEN_CALLED):
            continue
        for line, module, in_function in _imports(path):
            if in_function and (module == "ipc_taichi" or module.startswith("ipc_taichi.")):
                inside.setdefault(rel, []).append(f"{line}: {module}")
    assert inside == {}, inside


def test_cuda_presence_is_asked_of_one_function():
    """``gpus.cuda_present`` answers "is there CUDA?" for the library, the tests
    and the Makefile (which runs ``ipc_taichi/gpus.py`` as a script: the answer
    must be the same), and only gpus.py names the driver library."""
    import sys

    from ipc_taichi.gpus import cuda_present

    script = subprocess.run([sys.executable, str(ROOT / "ipc_taichi" / "gpus.py")],
                            capture_output=True, text=True, check=True, cwd="/")
    assert script.stdout.strip() == ("yes" if cuda_present() else "")
    assert "ipc_taichi/gpus.py" in (ROOT / "Makefile").read_text()
    driver = "lib" + "cuda"  # (spelled so that this file does not name it)
    naming = [str(p.relative_to(ROOT)) for p in _python_files()
              if f'"{driver}' in p.read_text() or f"'{driver}" in p.read_text()]
    assert naming == ["ipc_taichi/gpus.py"]
    assert driver not in (ROOT / "Makefile").read_text()


# ----------------------------------------------------------------- docs/architecture.md

ARCHITECTURE = ROOT / "docs" / "architecture.md"
_DOTTED = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)+$")
_PATH = re.compile(r"^[\w.]*[\w]/[\w./]*$|^\w+\.(py|md|json)$")


def _defined_at_top(path):
    """Names a module defines at its top level (functions, classes, constants)."""
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return names


def _resolves(dotted, modules, owners):
    """Whether ``dotted`` names something of the library: its first part a
    module (by its last name, e.g. ``streams`` or ``discover``) or a name some
    module defines (``CouplingModel``), the rest attributes or submodules."""
    import importlib

    first, *rest = dotted.split(".")
    bases = [m for m in modules if m.split(".")[-1] == first or m == first]
    bases += [f"{m}.{first}" for m in owners.get(first, ())]
    for base in bases:
        module, attrs = base, list(rest)
        if module not in modules:  # a name defined in a module
            module, attrs = base.rpartition(".")[0], [first] + attrs
        while attrs and f"{module}.{attrs[0]}" in modules:
            module = f"{module}.{attrs.pop(0)}"
        obj = importlib.import_module(module)
        try:
            for attr in attrs:
                obj = getattr(obj, attr)
        except AttributeError:
            continue
        return True
    return False


def test_architecture_cites_only_what_exists():
    """Every backticked dotted name of docs/architecture.md (``streams.tiled``,
    ``CouplingModel.resolve``, ``_engine.Workspace``) is a module, function,
    class or constant of the library, and every backticked path exists."""
    modules = _library_modules()
    owners = {}
    for name, path in modules.items():
        for defined in _defined_at_top(path):
            owners.setdefault(defined, []).append(name)
    cited = re.findall(r"`([^`\n]+)`", ARCHITECTURE.read_text())
    names = [c for c in cited if _DOTTED.match(c) and not c.endswith((".py", ".md"))]
    paths = [c for c in cited if _PATH.match(c)]
    missing = [c for c in names if not _resolves(c, modules, owners)]
    missing += [c for c in paths if not any((base / c).exists()
                                            for base in (ROOT, ROOT / "ipc_taichi"))]
    assert missing == []
    # the check sees the page: it cites both kinds
    assert "streams.tiled" in names and "cli/options.py" in paths and len(names) > 30


def _long_functions(limit=80):
    """``{module.function}`` (dotted, below ``ipc_taichi``) of the library's
    functions over ``limit`` lines of code, docstring excluded."""
    found = set()

    def visit(node, qual):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                visit(child, f"{qual}{child.name}.")
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = child.end_lineno - child.lineno + 1
                first = child.body[0]
                if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                        and isinstance(first.value.value, str):
                    lines -= first.end_lineno - first.lineno + 1
                if lines > limit:
                    found.add(f"{qual}{child.name}")
                visit(child, f"{qual}{child.name}.")

    for name, path in _library_modules().items():
        prefix = name.partition(".")[2]
        visit(ast.parse(path.read_text()), f"{prefix}." if prefix else "")
    return found


def test_functions_over_80_lines_are_the_ones_architecture_names():
    """No library function over 80 lines of code but those the table of
    docs/architecture.md names with a reason; and the table names no other
    (a function cut below 80 lines leaves the table)."""
    text = ARCHITECTURE.read_text()
    section = text.split("## Functions over 80 lines", 1)[1].split("\n## ", 1)[0]
    named = {m.group(1) for m in re.finditer(r"^\| `([\w.]+)` \|", section, re.M)}
    assert named, "the table is missing"
    assert _long_functions() == named
