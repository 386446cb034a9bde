"""The README's "Live memory" section, run as written on the README's own demo memory (P09): the
`memora remember` / `memora ask` lines, the Python block and the MCP client entry. A change to
`remember`, `LiveWriter` or `serve --writable` that breaks the first example a user copies fails here."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

import click
from click.testing import CliRunner

from memora_graph.cli import main

README = Path(__file__).resolve().parents[2] / "README.md"


def live_section() -> str:
    text = README.read_text()
    start = text.index("## Live memory")
    end = text.index("\n## ", start + 1)
    return text[start:end]


def blocks(section: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", section, flags=re.S)


def test_the_readme_live_memory_example_runs_as_written(small_bank, tmp_path, monkeypatch, capsys):
    section = live_section()
    shutil.copytree(small_bank[0], tmp_path / "banks" / "demo")
    monkeypatch.chdir(tmp_path)

    lines = [ln for block in blocks(section, "bash") for ln in block.splitlines() if ln.startswith("memora ")]
    assert [shlex.split(ln)[1] for ln in lines] == ["remember", "ask"]
    outputs = []
    for line in lines:
        args = shlex.split(line, comments=True)[1:]
        r = CliRunner().invoke(main, args)
        assert r.exit_code == 0, (line, r.output)
        outputs.append(r.output)
    remembered = json.loads(outputs[0].splitlines()[-1])
    assert remembered["duplicate"] is False and any(op["entity"].endswith(":cup") for op in remembered["ops"])
    said = line.split("#", 1)[1].split("(")[0].strip()  # the answer the README promises ("cupboard")
    assert outputs[1].startswith(said), outputs[1][:200]

    (code,) = blocks(section, "python")
    capsys.readouterr()
    exec(compile(code, "README.md (Live memory)", "exec"), {})
    printed = capsys.readouterr().out
    ops = eval(printed.strip())  # the list of (op, entity) pairs the example prints
    assert ops and all(op in {"ADD", "UPDATE", "DELETE", "NOOP"} for op, _ in ops)
    assert any(entity.endswith(":fridge") for _, entity in ops)

    entry = json.loads(re.search(r"`(\{\"command\": \"memora\".*?\})`", section, flags=re.S).group(1).replace("\n", " "))
    assert entry["command"] == "memora" and entry["args"][0] == "serve"
    serve = main.get_command(click.Context(main), "serve")
    ctx = serve.make_context("serve", entry["args"][1:])
    assert ctx.params["writable"] is True and ctx.params["participant"] == "P09"
