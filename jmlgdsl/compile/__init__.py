"""From a checked plant (jmlgdsl.lang.plant) to a Model: compile a .jmlg spec file or text, or a plant
already checked. ODE plants are linearised (compile.ode), the others lowered statement by statement
and block by block (compile.lower, compile.blocks); compile.assemble stacks the modes into the Model.
The compiler reads the values the checker evaluated; it evaluates nothing the user wrote."""

from .lower import compile_file, compile_plant, compile_text

__all__ = ["compile_file", "compile_text", "compile_plant"]
