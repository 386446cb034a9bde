"""The command line reads its choices from the registries, loads commands on demand, and
`memora --help` imports none of the heavy libraries."""

from __future__ import annotations

import json
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner

from memora_graph.cli import COMMANDS, PERF_COMMANDS, main, perf_group
from memora_graph.cli.options import LazyGroup


def _command(*path: str) -> click.Command:
    cmd = main
    for name in path:
        cmd = cmd.get_command(click.Context(cmd), name)
    return cmd


def _names():
    from memora_graph.agent.policies import answer_policy_names
    from memora_graph.bench.conditions import list_conditions
    from memora_graph.consolidate import processor_names
    from memora_graph.form.editor import editor_policy_names
    from memora_graph.llm import list_backends
    from memora_graph.retrieve.registry import families
    from memora_graph.retrieve.search import RECIPES

    return {"backends": list_backends(), "recipes": list(RECIPES), "conditions": list_conditions(),
            "processors": processor_names(), "answer policies": answer_policy_names(),
            "editor policies": editor_policy_names(), "families": families()}


# (registry, command path, arguments before the option, option, what an unknown name is called)
OPTIONS = [
    ("backends", ("build",), ["{tmp}/bank"], "--backend", "backend"),
    ("backends", ("consolidate",), ["{tmp}"], "--backend", "backend"),
    ("editor policies", ("build",), ["{tmp}/bank"], "--mode", "editor policy"),
    ("recipes", ("tool",), ["{tmp}", "search", "--participant", "P01"], "--recipe", "retrieval recipe"),
    ("families", ("tool",), ["{tmp}", "search", "--participant", "P01"], "--memory", "memory family"),
    ("families", ("tools",), [], "--memory", "memory family"),
    ("processors", ("consolidate",), ["{tmp}"], "--processor", "consolidation processor"),
    ("answer policies", ("bench", "run"), ["{tmp}", "--out", "{tmp}/run"], "--backend", "answer policy"),
    ("conditions", ("bench", "run"), ["{tmp}", "--out", "{tmp}/run"], "--conditions", "condition"),
]


@pytest.mark.parametrize("registry, path, before, option, what", OPTIONS,
                         ids=[f"{' '.join(o[1])} {o[3]}" for o in OPTIONS])
def test_every_registered_name_is_accepted_and_an_unknown_one_refused(tmp_path, registry, path, before, option, what):
    names = _names()[registry]
    assert names, f"no {registry} registered"
    cmd = _command(*path)
    args = [a.format(tmp=tmp_path) for a in before]
    dest = next(p.name for p in cmd.params if option in getattr(p, "opts", []))
    for name in names:
        ctx = cmd.make_context(" ".join(path), [*args, option, name])
        got = ctx.params[dest]
        assert got == name or got == [name], (option, name, got)
    result = CliRunner().invoke(main, [*path, *args, option, "no-such-name"])
    assert result.exit_code == 2, result.output
    assert f"no {what} 'no-such-name'; registered: " in result.output
    assert ", ".join(names[:2]) in result.output  # the message lists what exists


def test_a_name_registered_later_is_accepted(tmp_path):
    from memora_graph.consolidate import processors
    from memora_graph.consolidate.processors import register_processor
    from memora_graph.consolidate.run import deterministic_processors

    register_processor("scratch-rules", deterministic_processors)
    try:
        ctx = _command("consolidate").make_context("consolidate", [str(tmp_path), "--processor", "scratch-rules"])
        assert ctx.params["processor"] == "scratch-rules"
    finally:
        processors._REGISTRY.pop("scratch-rules")


def test_condition_aliases_and_lists(tmp_path):
    cmd = _command("bench", "run")
    ctx = cmd.make_context("run", [str(tmp_path), "--out", str(tmp_path / "r"), "--conditions", "memora,flat_1d_raw"])
    assert ctx.params["conditions"] == ["memora", "flat_1d_raw"]
    assert cmd.make_context("run", [str(tmp_path), "--out", str(tmp_path / "r")]).params["conditions"] == "all"


def test_participants_option_parses_once_for_every_command(tmp_path):
    ctx = _command("build").make_context("build", [str(tmp_path / "b"), "--participants", "P01, P02,P01"])
    assert ctx.params["participants"] == ["P01", "P02"]
    assert _command("build").make_context("build", [str(tmp_path / "b")]).params["participants"] is None
    for path, args in ((("build",), [str(tmp_path / "b")]), (("consolidate",), [str(tmp_path)]),
                       (("bench", "run"), [str(tmp_path), "--out", str(tmp_path / "r")])):
        bad = CliRunner().invoke(main, [*path, *args, "--participants", "P.1"])
        assert bad.exit_code == 2 and "'P.1' is not a participant id (1-64 characters" in bad.output, bad.output
        empty = CliRunner().invoke(main, [*path, *args, "--participants", ","])
        assert empty.exit_code == 2 and "no participant given" in empty.output, empty.output


def test_lazy_help_lines_match_the_commands():
    """`memora --help` lists lazy commands from COMMANDS without importing them: the recorded line
    must be the command's own."""
    for group, table in ((main, COMMANDS), (perf_group, PERF_COMMANDS)):
        for name, (_, short) in table.items():
            assert group.load(name).get_short_help_str(limit=10 ** 6) == short, name


def test_a_broken_command_module_is_an_error_not_a_missing_command():
    group = LazyGroup("g", lazy={"gone": ("memora_graph.no_such_module:cmd", "A command whose module is broken.")})
    assert "gone" in group.list_commands(click.Context(group))
    with pytest.raises(ModuleNotFoundError):
        group.load("gone")
    result = CliRunner().invoke(group, ["gone"])
    assert isinstance(result.exception, ModuleNotFoundError)


def test_help_imports_no_heavy_library():
    code = ("import sys\nsys.argv = ['memora', '--help']\nfrom memora_graph.cli import main\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "import json\nprint(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "Commands:" in out and "tool " in out
    loaded = set(json.loads(out.strip().splitlines()[-1]))
    heavy = {"torch", "sentence_transformers", "transformers", "polars", "pyarrow", "kuzu", "numpy", "pydantic",
             "onnxruntime", "networkx", "rich"}
    assert not loaded & heavy, f"`memora --help` imported {sorted(loaded & heavy)}"


def test_every_bank_command_still_gets_no_verify():
    for path in (("tool",), ("query",), ("consolidate",), ("bench", "run"), ("perf", "tools"), ("explore",)):
        assert any("--no-verify" in getattr(p, "opts", []) for p in _command(*path).params), path
    assert not any("--no-verify" in getattr(p, "opts", []) for p in _command("verify").params)
