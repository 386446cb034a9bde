"""The library's layers point one way: perceive -> form -> consolidate -> retrieve -> agent -> bench,
with the commands on top (memora_graph/cli/, the one package that imports click). A module may import
its own layer and the layers below it, never one above (every `import` is checked, function-level
ones included); the library never imports the test suite."""

from __future__ import annotations

import ast
from pathlib import Path

import memora_graph

PACKAGE = Path(memora_graph.__file__).parent
ORDER = ("base", "perceive", "form", "consolidate", "retrieve", "agent", "serve", "bench", "cli")
# first match wins: a module path (dotted, without the package name) -> its layer
RULES = (
    # the commands (the cli package, benchmark commands in cli/perf included), test helpers, and the
    # bank report that reads every layer's files (verify)
    ("cli", lambda m: m == "cli" or m.startswith(("cli.", "testing", "integrity.verify"))),
    ("perceive", lambda m: m.startswith("perceive")),
    ("form", lambda m: m.startswith("form")),
    ("consolidate", lambda m: m.startswith(("consolidate", "pipeline.")) or m == "pipeline"),
    ("retrieve", lambda m: m.startswith(("retrieve", "baselines", "explore", "transfer"))),
    ("agent", lambda m: m.startswith("agent")),
    ("serve", lambda m: m.startswith("serve")),  # the MCP server: over retrieve and agent, below the commands
    ("bench", lambda m: m.startswith("bench")),
    ("base", lambda m: True),
)


def layer_of(module: str) -> str:
    return next(layer for layer, match in RULES if match(module))


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).with_suffix("")
        parts = [p for p in rel.parts if p != "__init__"]
        out[".".join(parts)] = path
    return out


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
    return found


def test_every_module_imports_only_its_layer_and_below():
    problems = []
    for module, path in sorted(_modules().items()):
        if not module:
            continue
        mine = ORDER.index(layer_of(module))
        for line, name in _imports(path):
            if name.startswith(("tests", "support")):
                problems.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports the test suite ({name})")
            if not name.startswith("memora_graph."):
                continue
            target = name.removeprefix("memora_graph.")
            theirs = ORDER.index(layer_of(target))
            if theirs > mine:
                problems.append(f"{path.relative_to(PACKAGE.parent)}:{line} ({layer_of(module)}) imports {name} "
                                f"({layer_of(target)})")
    assert not problems, "imports against the layers:\n" + "\n".join(problems)


def test_the_layer_check_sees_a_violation(tmp_path):
    """The checker itself: an import from a higher layer, at function level, is found."""
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from memora_graph.bench.run import run_bench\n")
    assert _imports(bad) == [(2, "memora_graph.bench.run")]
    assert ORDER.index(layer_of("bench.run")) > ORDER.index(layer_of("form.editor"))
    assert layer_of("cli.consolidate") == "cli" and layer_of("baselines.flat1d") == "retrieve"
    assert layer_of("pipeline") == layer_of("pipeline.workers") == "consolidate"
    assert layer_of("cli.perf.tools") == layer_of("cli") == "cli" and layer_of("executors.tasks") == "base"
    assert layer_of("client") == "base"  # a name that merely starts with "cli" is not a command


def _imports_click(path: Path) -> list[int]:
    """The lines of `path` that import click (or a click submodule), function-level ones included."""
    return [line for line, name in _imports(path) if name == "click" or name.startswith("click.")]


def test_only_the_cli_package_imports_click():
    """Commands parse, call the library and render; the library itself never needs click."""
    problems = [f"{path.relative_to(PACKAGE.parent)}:{line} imports click"
                for module, path in sorted(_modules().items())
                if not (module == "cli" or module.startswith("cli."))
                for line in _imports_click(path)]
    assert not problems, "click outside memora_graph/cli/:\n" + "\n".join(problems)


def test_the_click_check_sees_an_import(tmp_path):
    """The checker itself: `import click` and a function-level `from click.x import y` are both found."""
    bad = tmp_path / "m.py"
    bad.write_text("import click\n\ndef f():\n    from click.testing import CliRunner\n")
    assert _imports_click(bad) == [1, 4]


def _private_imports(path: Path) -> list[tuple[int, str]]:
    """The (line, module.name) of every private name (one leading underscore) that `path` imports from
    another module, function-level imports included; `import x as _x` binds a public name privately
    and is not one."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            found += [(node.lineno, f"{'.' * node.level}{node.module or ''}.{a.name}") for a in node.names
                      if a.name.startswith("_") and not a.name.startswith("__")]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names
                      if any(part.startswith("_") and not part.startswith("__") for part in a.name.split("."))]
    return found


def test_no_module_imports_a_private_name_of_another():
    """A name with a leading underscore is its module's own: a module that needs it from elsewhere
    needs a public name (and the owner then knows it has a caller)."""
    problems = [f"{path.relative_to(PACKAGE.parent)}:{line} imports {name}"
                for module, path in sorted(_modules().items()) for line, name in _private_imports(path)]
    assert not problems, "private names imported across modules:\n" + "\n".join(problems)


def test_the_private_import_check_sees_one(tmp_path):
    """The checker itself: a function-level `from m import _x` is found; `import m as _m` is not."""
    bad = tmp_path / "m.py"
    bad.write_text("from memora_graph import text as _text\n\ndef f():\n    from memora_graph.bank import _PID, Bank\n")
    assert _private_imports(bad) == [(4, "memora_graph.bank._PID")]


def _import_graph(modules: dict[str, Path]):
    """Module -> the library modules it imports (any level; `from memora_graph.a import b` is
    the module `a.b` when that is a module, else `a`)."""
    import networkx as nx

    graph = nx.DiGraph()
    for module, path in modules.items():
        graph.add_node(module)
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}".removeprefix("memora_graph.")
                           in modules else node.module for a in node.names]
            for name in targets:
                if name.startswith("memora_graph."):
                    target = name.removeprefix("memora_graph.")
                    if target in modules and target != module:
                        graph.add_edge(module, target)
    return graph


def test_no_import_circles():
    """No two modules import each other, directly or around a circle (function-level imports
    count too): a circle is a layer inside a layer."""
    import networkx as nx

    graph = _import_graph({m: p for m, p in _modules().items() if m})
    circles = [c for c in nx.simple_cycles(graph) if not all(graph.has_edge(a, b) and
               (a.startswith(b + ".") or b.startswith(a + ".")) for a, b in zip(c, c[1:] + c[:1]))]
    assert not circles, "import circles:\n" + "\n".join(" -> ".join(c + c[:1]) for c in circles[:10])


def test_the_circle_check_sees_one(tmp_path, monkeypatch):
    """The checker itself: two modules that import each other (one at function level) are a circle."""
    import networkx as nx

    (tmp_path / "a.py").write_text("from memora_graph.b import x\n")
    (tmp_path / "b.py").write_text("def f():\n    from memora_graph.a import y\n")
    graph = _import_graph({"a": tmp_path / "a.py", "b": tmp_path / "b.py"})
    assert list(nx.simple_cycles(graph))
