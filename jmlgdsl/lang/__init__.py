"""The .jmlg language: parse text into a syntax tree (parse, syntax), evaluate what the user wrote
(evaluate, units) and check it into a Plant (check, probabilities), reporting located diagnostics
(report). It imports nothing from jmlgdsl.compile, which lowers a checked Plant to a Model."""
