"""The .jmlg grammar, installed inside the package as jmlgdsl.grammars."""
