"""sympy as a module imported on its first use: only plants written as equations (nonlinear
statements, ODEs) are evaluated symbolically, and importing sympy is a third of a command's start
(0.2 s of CPU) for every spec of matrices, FOPDT or ARX blocks.

    >>> from jmlgdsl.lang.symbolic import sp
    >>> sp.Integer(2) + 1
    3
"""

from __future__ import annotations

import importlib.util
import sys


def _lazy(name: str):
    """The module `name`, registered in sys.modules and executed at its first attribute access (the
    standard library's LazyLoader); the module itself where it is imported already."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.find_spec(name)
    spec.loader = importlib.util.LazyLoader(spec.loader)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


sp = _lazy("sympy")
