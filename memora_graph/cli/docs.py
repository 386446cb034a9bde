"""docs/cli.md, the command-line reference, generated from the commands' own `--help`.

    python -m memora_graph.cli.docs              # write docs/cli.md
    python -m memora_graph.cli.docs --check      # exit 1 when docs/cli.md is not what the commands say

Every command and subcommand of `memora` (lazy ones loaded) gets a section with its help text as
`memora COMMAND --help` prints it at a fixed width, so the page is the same on every machine.
tests/cli/test_docs.py fails when the page is stale or a command is missing from it.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import click

WIDTH = 100
HEADER = """# Command-line reference

Generated from each command's `--help` by `python -m memora_graph.cli.docs` (do not edit by hand:
`tests/cli/test_docs.py` fails when this page and the commands disagree). The README has one line per
command; the topic pages in this folder explain what the commands do.

"""


def commands(group: click.Group | None = None, path: tuple[str, ...] = ("memora",),
             parent: click.Context | None = None) -> Iterator[tuple[tuple[str, ...], click.Command, click.Context]]:
    """Every command under `group` (default: `memora`), depth first, with the context its help is
    rendered in."""
    if group is None:
        from memora_graph.cli import main as group
    ctx = click.Context(group, info_name=path[-1], parent=parent, terminal_width=WIDTH, max_content_width=WIDTH)
    yield path, group, ctx
    if isinstance(group, click.Group):
        for name in group.list_commands(ctx):
            cmd = group.get_command(ctx, name)
            if cmd is None or cmd.hidden:
                continue
            if isinstance(cmd, click.Group):
                yield from commands(cmd, (*path, name), ctx)
            else:
                sub = click.Context(cmd, info_name=name, parent=ctx, terminal_width=WIDTH, max_content_width=WIDTH)
                yield (*path, name), cmd, sub


def render() -> str:
    out = [HEADER, "## Commands\n"]
    entries = list(commands())
    for path, _, _ in entries:
        name = " ".join(path)
        out.append(f"- [`{name}`](#{_anchor(name)})")
    out.append("")
    for path, cmd, ctx in entries:
        name = " ".join(path)
        out.append(f"## {name}\n\n```text\n{cmd.get_help(ctx).rstrip()}\n```\n")
    return "\n".join(out)


def _anchor(title: str) -> str:
    return title.lower().replace(" ", "-")


def documented(markdown: str) -> set[str]:
    """The command names a reference page has a section for."""
    return {line[3:].strip() for line in markdown.splitlines() if line.startswith("## memora")}


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    check = "--check" in args
    rest = [a for a in args if a != "--check"]
    target = Path(rest[0]) if rest else Path("docs") / "cli.md"
    text = render()
    if check:
        if not target.exists() or target.read_text() != text:
            print(f"{target} is stale: run python -m memora_graph.cli.docs", file=sys.stderr)
            return 1
        print(f"{target} is up to date")
        return 0
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(text)
    print(f"wrote {target} ({sum(1 for _ in commands())} commands)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
