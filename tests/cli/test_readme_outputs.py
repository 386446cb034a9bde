"""The README's cheat-sheet keeps the checkout clean: every file a command writes goes under a folder
the README names and git ignores (`banks/` for banks, `out/` for everything else), never into the
checkout's root. Checked on the commands as the real click commands parse them, and by running the
two that write single files (`memora explore`, `memora export`) as written, from a scratch folder."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
from click.testing import CliRunner

from memora_graph.cli import main

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
OUT = "out/"


def cheat_sheet() -> list[str]:
    """Every `memora ...` line of the README's "Commands" block, comments dropped."""
    text = README.read_text()
    start = text.index("## Commands")
    block = re.search(r"```bash\n(.*?)```", text[start:], flags=re.S).group(1)
    return [shlex.join(shlex.split(line, comments=True)) for line in block.splitlines() if line.startswith("memora ")]


def written_paths(line: str) -> list[str]:
    """The files a command line writes: the value of its --out (as the real command parses it)."""
    words = shlex.split(line)[1:]
    cmd = main
    while isinstance(cmd, click.Group):
        cmd, words = cmd.get_command(click.Context(cmd), words[0]), words[1:]
    assert any("--out" in p.opts for p in cmd.params) or "--out" not in words, line
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w == "--out"]


def test_the_readme_names_the_output_folder_and_git_ignores_it():
    text = README.read_text()
    assert f"`{OUT}`" in text and "`banks/`" in text, "the README says where outputs go"
    ignored = (ROOT / ".gitignore").read_text().split()
    assert "/out/" in ignored and "/banks/" in ignored


def test_every_cheat_sheet_output_goes_under_out_or_banks():
    lines = cheat_sheet()
    assert len(lines) > 20
    outs = [(line, p) for line in lines for p in written_paths(line)]
    assert len(outs) >= 4, "the cheat-sheet writes files"
    for line, path in outs:
        assert path.startswith((OUT, "banks/")), f"`{line}` writes {path} outside {OUT}"
    for line in lines:
        words = shlex.split(line)
        if words[1] == "import":  # reads what export wrote
            assert words[3].startswith(OUT), line
        if words[1] in ("build", "remember", "import"):  # they create the bank they write
            assert words[2].startswith("banks/"), line


def test_explore_and_export_as_written_leave_the_folder_clean(small_bank, tmp_path, monkeypatch):
    """Run the README's explore and export lines (on the test bank, P37) from an empty folder: only
    `out/` appears."""
    bank, _ = small_bank
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    for line in cheat_sheet():
        words = shlex.split(line)
        if words[1] not in ("explore", "export"):
            continue
        args = [str(bank) if w == words[2] else "P37" if re.fullmatch(r"P\d\d", w) else w for w in words[1:]]
        r = runner.invoke(main, args)
        assert r.exit_code == 0, (line, r.output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert {p.suffix for p in (tmp_path / "out").iterdir()} == {".html", ".json"}
