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
