"""The .jmlg language: parse text into a syntax tree (parse, syntax), evaluate what the user wrote
(evaluate, units) and check it into a Plant (check, probabilities), reporting located diagnostics
(plant: the positions and the report, beside the checked plant's types). It imports nothing from
jmlgdsl.compile, which lowers a checked Plant to a Model."""
