"""One word per concept: "layout" is the engine's kernel loop (sweep, pixel,
lanes) and nothing else. The science region of a frame is a
``ScienceRegion`` (``products.plan``), how a stored frame holds the detector's
pixels an ``Arrangement`` (``products.arrangement``), a calibration input's
ramp-or-frames reading its ``stack``.

The scan reads every module of the package as Python (identifiers: names,
attributes, arguments, keywords, imports, definitions, and strings that are
one identifier, e.g. a dict key) and the package's file names."""

import ast
import re
from pathlib import Path

import ipc_taichi

PACKAGE = Path(ipc_taichi.__file__).parent
WORD = re.compile("layout", re.IGNORECASE)
IDENTIFIER = re.compile(r"^[A-Za-z_]\w*$")

# Matplotlib's own names (a figure's layout engine), not this package's words.
FOREIGN = {"tight_layout", "get_layout_engine"}
FOREIGN_KEYWORDS = {("subplots", "layout"), ("figure", "layout")}


def _engine(path):
    """The modules where "layout" is the kernel loop."""
    rel = path.relative_to(PACKAGE)
    return (rel.parts[0] == "bench" or (len(rel.parts) == 1 and rel.name.startswith("_"))
            or rel.name in ("engine.py", "coupling.py", "decoupling.py"))


def _call_name(func):
    return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")


def identifiers(tree):
    """(line, identifier) of every identifier in ``tree``, keywords of
    matplotlib's figure calls left out."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            skip = {kw.arg for kw in node.keywords
                    if (_call_name(node.func), kw.arg) in FOREIGN_KEYWORDS}
            for kw in node.keywords:
                if kw.arg is not None and kw.arg not in skip:
                    yield kw.lineno, kw.arg
        elif isinstance(node, ast.Name):
            yield node.lineno, node.id
        elif isinstance(node, ast.Attribute):
            yield node.lineno, node.attr
        elif isinstance(node, ast.arg):
            yield node.lineno, node.arg
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            yield node.lineno, node.name
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            for alias in node.names:
                yield node.lineno, alias.name
                if alias.asname:
                    yield node.lineno, alias.asname
            if isinstance(node, ast.ImportFrom) and node.module:
                yield node.lineno, node.module
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            if IDENTIFIER.match(node.value):
                yield node.lineno, node.value


def _found(source):
    return sorted({(line, name) for line, name in identifiers(ast.parse(source))
                   if WORD.search(name) and name not in FOREIGN})


def test_the_scan_finds_each_kind_of_identifier():
    """The scan is not blind: each way a name can carry the word is found."""
    source = ("import a.layouts\nfrom b import layout_of as lo\nclass Layout: pass\n"
              "def f(layout): return x.layout\nd = {'layout_reason': 1}\ng(layout=1)\n"
              "plt.subplots(1, 2, layout='constrained')\nfig.tight_layout()\n")
    names = {name for _, name in _found(source)}
    assert names == {"a.layouts", "layout_of", "Layout", "layout", "layout_reason"}
    assert {line for line, name in _found(source) if name == "layout"} == {4, 6}


def test_layout_is_only_the_kernel_loop():
    outside = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if _engine(path):
            continue
        rel = path.relative_to(PACKAGE)
        if WORD.search(str(rel)):
            outside.append(f"{rel}: file name")
        outside += [f"{rel}:{line}: {name}" for line, name in _found(path.read_text())]
    assert outside == []


def test_the_engine_keeps_its_word():
    """The kernel loop's names are where the rule says (the scan has
    something to leave alone: a renamed engine would make it vacuous)."""
    engine = [p for p in PACKAGE.rglob("*.py") if _engine(p)]
    assert any(_found(p.read_text()) for p in engine)
    assert (PACKAGE / "_layouts.py").exists()
