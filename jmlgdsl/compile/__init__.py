"""From a checked plant (jmlgdsl.lang) to a Model: compile a .jmlg spec file or text, or an already
parsed Spec. ODE plants are linearised (compile.ode), the others lowered statement by statement and
block by block (compile.lower, compile.blocks); compile.assemble stacks the modes into the Model."""

from .lower import compile_file, compile_spec, compile_text

__all__ = ["compile_file", "compile_text", "compile_spec"]
