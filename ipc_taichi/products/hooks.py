"""Configured subclasses of a Step: the post-hook string a command line can carry.

stpipe 1.1 reads a hook string ``"pkg.Class(kw=value)"`` by splitting the whole string
at its last dot, so arguments holding a dot (a file name, a decimal number) turn the
hook into a shell command. A subclass with the parameters built in is named with no
arguments: :func:`configured_subclass` (used by
:func:`ipc_taichi.products.jwst_hooks.configured_step` and
:func:`ipc_taichi.products.roman_step.roman_configured_step`).
"""

import os
import re
import sys

__all__ = ["configured_subclass", "spec_parameters"]


def spec_parameters(step_class):
    """The parameter names of ``step_class``'s own ``spec``."""
    names = []
    for line in step_class.spec.splitlines():
        name = line.split("=", 1)[0].strip()
        if "=" in line and name and not name.startswith("#"):
            names.append(name)
    return names


def configured_subclass(base, name, parameters, depth=1):
    """A subclass of the Step class ``base`` named ``name`` whose parameters default
    to ``parameters`` (its ``spec`` with those defaults, so ``.call()``, ``strun`` and a
    hook all start from them; values given still win), defined in the module ``depth``
    frames up the stack (the caller's caller by default), so that ``"module.name"``
    imports it. Unknown parameter names are refused."""
    known = set(spec_parameters(base))
    unknown = sorted(set(parameters) - known)
    if unknown:
        raise ValueError(f"{name}: unknown parameter(s) {', '.join(unknown)}; "
                         f"{base.__name__} takes {', '.join(sorted(known))}")
    lines = []
    for line in base.spec.splitlines():
        key = line.split("=", 1)[0].strip()
        if key in parameters:
            value = parameters[key]
            literal = repr(str(value)) if isinstance(value, (str, os.PathLike)) else repr(value)
            line, count = _DEFAULT.subn(f"default={literal})", line, count=1)
            if not count:
                raise ValueError(f"{name}: {key} has no default in {base.__name__}'s spec")
        lines.append(line)
    module = sys._getframe(depth + 1).f_globals.get("__name__", __name__)
    return type(name, (base,), {"spec": "\n".join(lines), "__module__": module,
                                "__qualname__": name,
                                "__doc__": f"{base.__name__} with {dict(parameters)}"})


# the default of one spec line: "default=...)" up to the closing parenthesis
_DEFAULT = re.compile(r"default=(?:'[^']*'|\"[^\"]*\"|[^)]*)\)")
