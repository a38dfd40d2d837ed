"""The package's layers import one way: no cycles between files or packages, nothing from above.

The layers, lowest first (docs/architecture.md draws them): leaf helpers; the model type and the
data and metric helpers that know only names and arrays; the language; the compiler; inference and
simulation; the studies, learning and figures built on them; the command line. Within them, the
monitor's store is the one place that speaks SQL, and the page reads only through its queries.
"""

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jmlgdsl"
LAYERS = [
    {"errors", "names", "seeds", "gaussian", "output", "version", "sealed"},
    {"model", "data"},
    {"lang"},
    {"compile"},
    {"infer", "simulation"},
    {"diagnosis"},
    {"studies", "learn", "fitting", "monitor"},
    {"page"},
    {"commands", "cli", "__main__", "jmlgdsl"},
]
RANK = {name: rank for rank, names in enumerate(LAYERS) for name in names}


def modules():
    """{dotted module name: path} for every file of the package."""
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports(name, path, known):
    """The package's modules that `name` imports (a package's __init__ re-exporting its own
    submodules does not count: that is the package's entry point, not a dependency)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package.split(".")[:len(package.split(".")) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            candidates = [target] + [f"{target}.{alias.name}" for alias in node.names]
        elif isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        else:
            continue
        found |= {c for c in candidates if c in known and c != name}
    if path.name == "__init__.py":
        found = {t for t in found if not t.startswith(name + ".")}
    return found


def graph():
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def layer(name):
    """The layer a module belongs to: its subpackage, or its own name for a top-level file."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def cycle(edges):
    """One cycle of a directed graph as a list of nodes, or None."""
    state, path = {}, []

    def visit(node):
        state[node] = "open"
        path.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = "done"
        path.pop()
        return None

    for node in sorted(edges):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_every_module_has_a_layer():
    assert {layer(name) for name in graph()} <= set(RANK)


def test_no_cycle_between_files():
    assert cycle(graph()) is None


def test_no_cycle_between_packages_and_no_import_from_a_layer_above():
    packages = {}
    for name, targets in graph().items():
        for target in targets:
            a, b = layer(name), layer(target)
            if a != b:
                packages.setdefault(a, set()).add(b)
                assert RANK[b] <= RANK[a], f"{name} imports {target}, from a layer above it"
    assert cycle(packages) is None


@pytest.mark.parametrize("edges, expected", [({"a": {"b"}, "b": {"c"}, "c": {"a"}}, ["a", "b", "c", "a"]),
                                             ({"a": {"b"}, "b": set()}, None)])
def test_the_cycle_finder_finds_cycles(edges, expected):
    assert cycle(edges) == expected


# The package root holds the model and the data, the public entry points and the leaf helpers that
# more than one layer uses; the rest lives in packages whose names say what they hold, each helper in
# the lowest package that uses it. At most twelve modules, so the root reads at a glance.
ROOT_MODULES = {"__init__", "__main__", "cli", "version", "errors", "names", "seeds", "gaussian", "output", "model",
                "data", "sealed"}
PACKAGES = {"lang", "compile", "infer", "simulation", "diagnosis", "studies", "learn", "fitting", "monitor", "page",
            "commands", "grammars"}


def test_the_root_holds_only_the_model_entry_points_and_leaf_helpers():
    assert len(ROOT_MODULES) <= 12
    assert {p.stem for p in PACKAGE.glob("*.py")} == ROOT_MODULES
    assert {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()} == PACKAGES


def is_command(name) -> bool:
    """Whether a module is a subcommand: one of jmlgdsl/commands/ whose name has no leading underscore (a
    module with one holds what several commands share, imported through jmlgdsl.commands)."""
    return name.startswith("jmlgdsl.commands.") and not name.rsplit(".", 1)[1].startswith("_")


def test_no_command_imports_another_command_or_a_shared_module_but_through_the_package():
    for name, targets in graph().items():
        if is_command(name):
            assert not {t for t in targets if t.startswith("jmlgdsl.commands.")}, name


def test_every_command_module_is_short_parse_call_print():
    """A command parses, calls the library and prints: every module of jmlgdsl/commands/ under 100
    lines."""
    long = {path.name: n for path in (PACKAGE / "commands").glob("*.py")
            if (n := len(path.read_text().splitlines())) >= 100}
    assert long == {}


CHECKED_PLANT = "jmlgdsl.lang.plant"  # the checked plant's types: names, numbers, arrays, ODEs
REPORT = "jmlgdsl.lang.diagnostics"  # source positions and the report of located diagnostics
CHECKER_ENTRIES = {"check_spec_file", "check_text", "check_ode_file"}  # lang.check: a spec file or text to a plant


def language_imports(name, path):
    """(module of jmlgdsl.lang, names) for each import of the language in a module."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package.split(".")[:len(package.split(".")) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            names = {alias.name for alias in node.names}
            if target == "jmlgdsl.lang":  # `from ..lang import plant`: the names are modules
                found += [(f"{target}.{n}", set()) for n in names]
            elif target.startswith("jmlgdsl.lang."):
                found.append((target, names))
        elif isinstance(node, ast.Import):
            found += [(alias.name, set()) for alias in node.names if alias.name.startswith("jmlgdsl.lang")]
    return found


def test_the_compiler_reads_the_checked_plant_and_evaluates_nothing():
    """compile/ takes from the language only the checked plant's types (lang.plant), the positions and
    report its diagnostics go to (lang.diagnostics) and the checker's entry points that turn a spec file or
    text into a checked plant: never the evaluator, the parser, the syntax tree, durations or limits. What
    the user wrote is evaluated once, by the checker."""
    compiler = {name: path for name, path in modules().items() if layer(name) == "compile"}
    assert compiler
    for name, path in compiler.items():
        for target, names in language_imports(name, path):
            allowed = target in (CHECKED_PLANT, REPORT) or (target == "jmlgdsl.lang.check" and names <= CHECKER_ENTRIES)
            assert allowed, f"{name} imports {sorted(names) or 'the module'} from {target}"


def test_the_pin_sees_an_import_of_the_evaluator(tmp_path):
    path = tmp_path / "lower.py"
    path.write_text("from ..lang.evaluate import evaluate_number\nfrom ..lang.plant import Plant\n")
    assert language_imports("jmlgdsl.compile.lower", path) == [("jmlgdsl.lang.evaluate", {"evaluate_number"}),
                                                               (CHECKED_PLANT, {"Plant"})]


SOURCES = "jmlgdsl.monitor.sources"
CONTRACT = f"{SOURCES}.contract"
BEYOND_SOURCES = ("jmlgdsl.monitor.store", "jmlgdsl.monitor.live",
                  "jmlgdsl.monitor.sinks", "jmlgdsl.monitor.shards", "jmlgdsl.page")


def test_the_sources_read_and_hand_over_and_know_nothing_of_the_store_or_the_page():
    found = {name: targets for name, targets in graph().items() if name.startswith(SOURCES + ".")}
    assert CONTRACT in found
    for name, targets in found.items():
        assert not {t for t in targets if t.startswith(BEYOND_SOURCES)}, name


def test_every_scheme_is_a_module_whose_sources_keep_the_contract():
    """A new source is a module of monitor/sources with open_source, and its line in SCHEMES; each
    source class in it has what the monitor asks of one (the contract's Source: rows, start,
    acknowledge, stop)."""
    import importlib
    import inspect

    from jmlgdsl.monitor.sources import SCHEMES
    from jmlgdsl.monitor.sources.contract import Source

    asked = ({name for name in vars(Source) if not name.startswith("_")} | set(Source.__annotations__)) - {"name"}
    for scheme in SCHEMES.values():
        try:
            module = importlib.import_module(f"{SOURCES}.{scheme.module}")
        except ModuleNotFoundError:
            assert scheme.needs is not None, scheme
            continue
        assert callable(module.open_source), scheme
        classes = [c for _, c in inspect.getmembers(module, inspect.isclass)
                   if c.__module__ == module.__name__ and hasattr(c, "start")]
        assert classes, scheme
        for source in classes:  # (`name` is each instance's own)
            assert asked <= set(dir(source)), source


def test_the_monitor_takes_sources_through_the_contract_and_the_registry_only():
    """live.py and shards.py name no protocol: the monitor takes the contract's items, the shards open
    their source through the scheme registry."""
    edges = graph()
    protocols = {t for t in edges if t.startswith(SOURCES + ".") and t != CONTRACT}
    for name in ("jmlgdsl.monitor.live", "jmlgdsl.monitor.shards"):
        assert not edges[name] & protocols, name


ALGORITHM_TABLE = "jmlgdsl.infer.algorithms"  # the one place a filter's name means what it can do


def name_checks(path, names) -> list[str]:
    """The comparisons (==, !=, in, not in) of a module against a filter's name: `x == "imm"`,
    `x in ("pf", "exact")`; each as its source text."""
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare) and any(isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn))
                                                 for op in node.ops):
            constants = {c.value for side in [node.left, *node.comparators] for c in ast.walk(side)
                         if isinstance(c, ast.Constant) and isinstance(c.value, str)}
            if constants & names:
                found.append(ast.unparse(node))
    return found


def test_no_module_but_the_algorithm_table_asks_for_a_filter_by_its_name():
    """What a filter can do (particles, smoothing, units stepped together) is data on its row of the
    table: a new filter is one row, with no `algorithm == "imm"` anywhere else to find and mend."""
    from jmlgdsl.infer import ALGORITHMS

    checks = {name: name_checks(path, set(ALGORITHMS)) for name, path in modules().items() if name != ALGORITHM_TABLE}
    assert {name: found for name, found in checks.items() if found} == {}


def test_the_pin_sees_a_name_check(tmp_path):
    path = tmp_path / "fleet.py"
    path.write_text('a = f.algorithm == "imm"\nb = algorithm in ("exact", "imm")\nc = algorithm == "other"\n')
    assert name_checks(path, {"imm", "exact"}) == ["f.algorithm == 'imm'", "algorithm in ('exact', 'imm')"]


STORE = "jmlgdsl.monitor.store"  # the one package that speaks SQL
DRIVERS = {"sqlite3", "psycopg"}
SQL = re.compile(r"\b(SELECT|INSERT INTO|UPDATE \w+ SET|DELETE FROM|CREATE (TABLE|INDEX)|ALTER TABLE|DROP TABLE)\b")


def speaks_sql(path) -> list[str]:
    """What in a file speaks to a database: an import of a driver, text of SQL, the store's own
    connection (`store.db`)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [f"imports {a.name}" for a in node.names if a.name.split(".")[0] in DRIVERS]
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module.split(".")[0] in DRIVERS:
            found.append(f"imports from {node.module}")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and SQL.search(node.value):
            found.append(f"SQL on line {node.lineno}: {SQL.search(node.value)[0]}")
        elif isinstance(node, ast.Attribute) and node.attr == "db":
            found.append(f"the store's connection (.db) on line {node.lineno}")
    return found


def test_only_the_store_speaks_sql():
    """A reader or writer of the store (the page, the sinks, the commands) goes through its methods,
    so a store kept another way is a new backend of jmlgdsl/monitor/store alone."""
    for name, path in modules().items():
        if name != STORE and not name.startswith(STORE + "."):
            assert not speaks_sql(path), f"{name}: {speaks_sql(path)}"


def test_the_page_reads_the_monitor_only_through_the_store():
    page = {name: targets for name, targets in graph().items() if layer(name) == "page"}
    assert page
    for name, targets in page.items():
        assert {t for t in targets if t.startswith("jmlgdsl.monitor")} <= {STORE}, name


def test_the_pin_sees_a_driver_sql_and_the_connection(tmp_path):
    path = tmp_path / "views.py"
    path.write_text("import sqlite3\nfrom psycopg import sql\nROWS = 'SELECT t FROM result'\n"
                    "store.db.execute(ROWS)\nTEXT = 'select the rows to show'\n")
    assert speaks_sql(path) == ["imports sqlite3", "imports from psycopg", "SQL on line 3: SELECT",
                                "the store's connection (.db) on line 4"]


def test_the_report_is_below_the_syntax_tree_and_the_checked_plant():
    """Positions and diagnostics (lang.diagnostics) are the language's floor: the syntax tree, the checked
    plant and every checking step import them, and they import nothing of the language but its limits,
    so loading a spec never runs up and down between the plant's types and the checking steps."""
    edges = graph()
    assert edges[REPORT] & set(modules()) <= {"jmlgdsl.lang.limits", "jmlgdsl.errors"}
    assert REPORT in edges[CHECKED_PLANT] and REPORT in edges["jmlgdsl.lang.syntax"]
    assert not {name for name, targets in edges.items() if CHECKED_PLANT in targets} & {
        "jmlgdsl.lang.syntax", "jmlgdsl.lang.evaluate", "jmlgdsl.lang.durations", "jmlgdsl.lang.probabilities",
        "jmlgdsl.lang.unknowns", "jmlgdsl.lang.declarations"}


def public_definitions(kind):
    """{name: [modules defining it]} for every public class (kind ast.ClassDef) or function
    (ast.FunctionDef) defined at a module's top level."""
    found = {}
    for name, path in modules().items():
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, kind) and not node.name.startswith("_"):
                found.setdefault(node.name, []).append(name)
    return found


def test_no_two_classes_share_a_name():
    """A class name means one thing in the whole package: a reader (or an import) never has to ask
    which of two `Linearize`s is meant."""
    assert {name: where for name, where in public_definitions(ast.ClassDef).items() if len(where) > 1} == {}


def test_the_checker_entry_points_have_names_of_their_own():
    """`check_spec_file` checks a spec; no other module's function (such as the check that an output
    file can be written) goes by the same name."""
    functions = public_definitions(ast.FunctionDef)
    assert CHECKER_ENTRIES <= {name for name, where in functions.items() if "jmlgdsl.lang.check" in where}
    assert {name: functions[name] for name in CHECKER_ENTRIES if len(functions[name]) > 1} == {}


def test_a_spec_of_matrices_runs_without_importing_sympy_or_other_commands(tmp_path):
    """Start-up is paid per command: `run` on a spec of matrices and blocks imports neither sympy
    (equations only) nor the modules of the other commands; a spec of equations still gets sympy."""
    import subprocess
    import sys

    root = PACKAGE.parent
    probe = ("import sys; from jmlgdsl.cli import main; main(sys.argv[1:]); "
             "print(sorted(m for m in ('sympy.core', 'jmlgdsl.commands.monitor', 'jmlgdsl.commands.learn') "
             "if m in sys.modules))")
    ran = subprocess.run([sys.executable, "-c", probe, "run", str(root / "specs" / "dryer.jmlg"),
                          str(root / "examples" / "dryer_seq1.csv"), "-o", str(tmp_path / "out.csv")],
                         capture_output=True, text=True, check=True)
    assert ran.stdout.splitlines()[-1] == "[]"
    ran = subprocess.run([sys.executable, "-c", probe, "check", str(root / "specs" / "cstr4.jmlg")],
                         capture_output=True, text=True, check=True)
    assert ran.stdout.splitlines()[-1] == "['sympy.core']"
