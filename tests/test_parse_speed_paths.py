"""A matrix literal of numbers only on one line is read as one token (a learned spec's matrices hold
hundreds of thousands of entries); it must give exactly what the general `row` rule gives: the same
number nodes at the same positions, the same values, the same errors. Units and time references, which
are bracketed too, must not be taken for it."""

import warnings

import numpy as np
import pytest
from conftest import errors_of
from lark import Token

from jmlgdsl.compile.lower import compile_text
from jmlgdsl.errors import SpecError
from jmlgdsl.lang.evaluate import numeric
from jmlgdsl.lang.limits import MAX_NESTING
from jmlgdsl.lang.parse import grammar, parse_text
from jmlgdsl.lang import syntax
from jmlgdsl.lang.syntax import Expr, Pos

SPEC = """\
plant p
sample 1 s
input u [m3/h] = 0
output y [2]
state x1 [1/s], x2
modes a
mode a {
  A = MATRIX
  F = [1; 0]
  C = [1 0]
  B = [0.1 0; 0 0.1]
  D = [0.1]
}
"""


def spec_with(matrix: str) -> str:
    return SPEC.replace("MATRIX", matrix)


def matrix_node(text: str) -> Expr:
    """The syntax node of the matrix written after `A = ` on line 8."""
    return parse_text(spec_with(text)).blocks[0].statements[0].expr


def one_token(text: str) -> bool:
    """Whether lark reads the matrix of line 8 as one NUMERIC_MATRIX token (else as rows of entries)."""
    tree = grammar().parse(spec_with(text))
    children = next(m for m in tree.find_data("matrix") if m.meta.line == 8).children
    return len(children) == 1 and isinstance(children[0], Token) and children[0].type == "NUMERIC_MATRIX"


def outcome(text: str):
    """What compiling gives: the model's arrays and the warnings, or the errors, each with its place."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # the compiler's own warnings: a file some other test left open, collected meanwhile, is not one
        warnings.simplefilter("ignore", ResourceWarning)
        try:
            model = compile_text(text).to_dict()
        except SpecError as exc:
            return [(d.line, d.column, d.message) for d in exc.diagnostics]
    return model, [str(w.message) for w in caught]


def no_lookup(node):
    raise AssertionError(f"a numbers-only matrix looked up {node}")


def test_numbers_only_matrix_is_one_token_with_each_entry_at_its_column():
    assert one_token("[1 -2; 3e-1, 4]")
    node = matrix_node("[1 -2; 3e-1, 4]")
    assert node == Expr("matrix", ((Expr("number", (1.0,), Pos(8, 8)), Expr("number", (-2.0,), Pos(8, 10))),
                                   (Expr("number", (0.3,), Pos(8, 14)), Expr("number", (4.0,), Pos(8, 20)))),
                        Pos(8, 7))


def test_numbers_only_matrix_has_the_values_of_the_general_path():
    fast, general = matrix_node("[1 -2; 3e-1, 4]"), matrix_node("[(1) -2; 3e-1, 4]")
    assert not one_token("[(1) -2; 3e-1, 4]")
    value = numeric(fast, no_lookup)
    assert value.dtype == np.float64 and value.tolist() == [[1.0, -2.0], [0.3, 4.0]]
    np.testing.assert_array_equal(value, numeric(general, no_lookup))
    a, b = outcome(spec_with("[1 -2; 3e-1, 4]")), outcome(spec_with("[(1) -2; 3e-1, 4]"))
    assert a == b and a[0]["A"]["data"] == [1.0, -2.0, 0.3, 4.0]


# A form feed is white space to the grammar but not to the one-token literal: the same text, at the same
# columns, then goes the general way.
@pytest.mark.parametrize("literal", [
    "[1 -2; 3e-1, 4]", "[ 0.5\t.5 ;5. -1.5e+2 ]", "[1,2 ,3]", "[-0 00 +7]", "[1e308; 2E-3]",
    "[0.12345678901234567 -3.4e-05]", "[1e999]", "[1 2; 3]",
])
def test_one_token_and_general_path_give_the_same_nodes_and_errors(literal):
    general = literal[:-1] + "\f]"
    assert one_token(literal) and not one_token(general)
    assert matrix_node(literal) == matrix_node(general)
    assert outcome(spec_with(literal)) == outcome(spec_with(general))


def test_an_overflowing_entry_is_reported_at_the_entry():
    found = [(d.line, d.column) for d in errors_of(spec_with("[1 1e999; 0 1]"), "p.jmlg") if "finite" in d.message]
    assert found == [(8, 10)]
    nested = [(d.line, d.column) for d in errors_of(spec_with("[1 (2 * 1e308 * 10); 0 1]"), "p.jmlg")
              if "finite" in d.message]
    assert nested == [(8, 11)]  # the product inside the parentheses


def test_a_transition_row_is_reported_at_its_first_entry():
    text = spec_with("[1 0; 0 1]").replace("modes a\n", "modes a, b\ntransitions [0.9 0.1;  0.5 0.6]\n")
    text = text + "mode b like a\n"
    (d,) = errors_of(text, "p.jmlg")
    assert (d.line, d.column, d.message) == (7, 24, "transition row 2 (b) sums to 1.1, not 1")


def test_a_one_token_matrix_at_the_nesting_limit_is_too_deep_at_its_last_row():
    signs = "-" * (MAX_NESTING - 1)
    for literal in ("[0.1 0.2; 0.3 0.4]", "[0.1 0.2; 0.3 0.4\f]"):
        (d,) = errors_of(spec_with(signs + literal), "p.jmlg")
        assert (d.line, d.column) == (8, 7 + len(signs) + 10) and d.message.startswith("expression nested too deeply")
    model, caught = outcome(spec_with(signs[1:] + "[0.1 0.2; 0.3 0.4]"))  # one sign fewer: not too deep
    assert model["A"]["data"] == [0.1, 0.2, 0.3, 0.4] and caught == []


def test_units_time_references_and_other_matrices_still_parse():
    spec = parse_text(spec_with("[1 0; 0 1]"))
    assert [(d.name.text, d.unit) for d in spec.decls] == [("u", "m3/h"), ("y", "2"), ("x1", "1/s"), ("x2", None)]
    model = compile_text(SPEC.replace("  A = MATRIX\n", "  x1[t] = 0.5 * x1[t-1] + x2[t-1]\n  x2[t] = -x2[t-1]\n  x1[0] = 2\n"))
    assert model.A[0].tolist() == [[0.5, 1.0], [0.0, -1.0]] and model.mu0[0].tolist() == [2.0, 0.0]
    mixed = compile_text(spec_with("[(0.5 - 0.25) -0.5;\n (e / 10) exp(-1)]").replace("plant p", "plant p\nlet e = 3"))
    assert mixed.A[0].tolist() == [[0.25, -0.5], [0.3, np.exp(-1)]]
    assert matrix_node("[]") == Expr("matrix", (), Pos(8, 7))
    assert matrix_node("[1 2;\n 3 4]").args[1][1] == Expr("number", (4.0,), Pos(9, 4))


@pytest.mark.parametrize("old, new, error", [
    ("modes a\n", "modes a\ninitial )\n", (7, 9, "unexpected ')'; expected '[', 'otherwise', 'stay' or a name")),
    ("  A = MATRIX", "  A = [1 2] [3]", (8, 13, "unexpected '[3]'; expected '*', '**', '+', '-', '/', ';', '^', 'der', "
                                                "'noise', '}', a name or a reference like h[t]")),
    ("  A = MATRIX", "  A = [1 2", (9, 5, "unexpected '='; expected '(', ',', ';', ']', a name or a number")),
])
def test_syntax_errors_around_matrices_read_as_before(old, new, error):
    assert outcome(SPEC.replace(old, new)) == [error]


def test_a_numbers_only_matrix_is_evaluated_without_a_node_per_entry(monkeypatch):
    """A learned spec's 19 matrices of 52 x 52 would take a second to load if every entry became a
    number node: the values are read from the token, the nodes made only when something walks them."""
    made = []

    class Counted(syntax.Expr):
        def __new__(cls, op, *args, **kwargs):
            made.append(op)
            return super().__new__(cls)

    monkeypatch.setattr(syntax, "Expr", Counted)
    rows = np.arange(2500.0).reshape(50, 50) / 7
    literal = "[" + "; ".join(" ".join(map(repr, row.tolist())) for row in rows) + "]"
    node = parse_text(spec_with(literal)).blocks[0].statements[0].expr
    value = numeric(node, no_lookup)
    assert value.tobytes() == rows.tobytes()
    unwalked = made.count("number")
    assert unwalked < 10  # the spec's other numbers
    last = node.args[49][49]
    assert (last.op, last.args, last.pos) == ("number", (rows[49, 49],), Pos(8, 7 + literal.rindex(" ") + 1))
    assert made.count("number") == unwalked + 2500  # walked: every entry, each at its column
