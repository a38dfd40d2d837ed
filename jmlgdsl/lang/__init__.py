"""The .jmlg language: parse text into a syntax tree (parse, syntax), then check it (check): its
declarations (declarations, probabilities, unknowns with their priors), then every mode's values
(values: statements, equations), evaluating what the user wrote (evaluate, durations) into a
checked Plant (plant: the values the compiler reads). Every step reports its located diagnostics to
one Report (report: the source positions and the report, beneath all the others). It imports
nothing from jmlgdsl.compile, which lowers a checked Plant to a Model."""
