"""What the `memora` commands share: subcommands loaded on demand, the participants option,
progress bars, backend options, the output-format options, and click choices read from the registries.

Only click is imported at module level, so that `memora --help` imports no command module, no
polars, numpy or torch: a group lists its lazy subcommands from the one-line help recorded next
to their import path (tests/cli/test_cli_options.py checks the two agree).
"""

from __future__ import annotations

import functools
import importlib
import json
from collections.abc import Callable, Iterable

import click

from memora_graph.output import FORMATS, ROWS_JSON


# -- subcommands loaded on demand ------------------------------------------------------------
class LazyGroup(click.Group):
    """A group whose subcommands are imported when one is run (or its help is asked for).

    `lazy` maps a command name to ("module:attribute", one-line help). `on_load(command)` is
    called once on every command this group loads or holds (the integrity layer adds
    `--no-verify` there). MemoraErrors become `Error: ...` and exit code 1, never a traceback.
    """

    def __init__(self, *args, lazy: dict[str, tuple[str, str]] | None = None,
                 on_load: Callable[[click.Command], None] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy = dict(lazy or {})
        self.on_load = on_load
        self._prepared: set[str] = set()

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*self.commands, *self.lazy})

    def load(self, name: str) -> click.Command | None:
        """The command `name`, importing its module on first use (an ImportError propagates:
        a broken module is an error, never a silently missing command)."""
        cmd = self.commands.get(name)
        if cmd is None and name in self.lazy:
            module, attr = self.lazy[name][0].split(":")
            cmd = getattr(importlib.import_module(module), attr)
            self.commands[name] = cmd
        if cmd is not None and name not in self._prepared:
            self._prepared.add(name)
            if isinstance(cmd, LazyGroup) and cmd.on_load is None:
                cmd.on_load = self.on_load
            elif self.on_load is not None:
                self.on_load(cmd)
        return cmd

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        return self.load(cmd_name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        from click.utils import make_default_short_help

        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max((len(n) for n in names), default=0)  # as click.Group does
        rows = []
        for name in names:
            if name in self.commands:
                cmd = self.commands[name]
                if cmd.hidden:
                    continue
                rows.append((name, cmd.get_short_help_str(limit)))
            else:
                rows.append((name, make_default_short_help(self.lazy[name][1], limit)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def invoke(self, ctx: click.Context):
        from memora_graph.errors import MemoraError

        try:
            return super().invoke(ctx)
        except MemoraError as exc:
            raise click.ClickException(str(exc)) from exc
        except KeyboardInterrupt:  # Ctrl-C before a command says more (`build` says how to resume): one line
            click.echo(f"memora{' ' + ctx.invoked_subcommand if ctx.invoked_subcommand else ''}: interrupted", err=True)
            raise click.exceptions.Exit(130) from None


# -- choices from the registries ---------------------------------------------------------------
class RegistryChoice(click.Choice):
    """A click choice whose names come from a registry, looked up when needed (parsing a value,
    or help), so that defining the option imports nothing. An unknown name is refused
    with the registered ones listed."""

    def __init__(self, names: Callable[[], Iterable[str]], what: str):
        self._names, self.what = names, what
        self.case_sensitive = True

    @property
    def choices(self) -> tuple[str, ...]:
        return tuple(self._names())  # asked each time: a name registered later is accepted too

    def get_invalid_choice_message(self, value, ctx) -> str:
        return f"no {self.what} {value!r}; registered: {', '.join(self.choices)}"


def backend_names() -> list[str]:
    from memora_graph.llm import list_backends

    return list_backends()


def recipe_names() -> list[str]:
    from memora_graph.retrieve.search import RECIPES

    return list(RECIPES)


def processor_names() -> list[str]:
    from memora_graph.consolidate import processor_names as names

    return names()


def condition_names() -> list[str]:
    from memora_graph.bench.conditions import list_conditions

    return list_conditions()


def answer_policy_names() -> list[str]:
    from memora_graph.agent.policies import answer_policy_names as names

    return names()


def editor_policy_names() -> list[str]:
    from memora_graph.form.editor import editor_policy_names as names

    return names()


def family_names() -> list[str]:
    from memora_graph.retrieve.registry import families

    return families()


BACKEND = RegistryChoice(backend_names, "backend")
RECIPE = RegistryChoice(recipe_names, "retrieval recipe")
PROCESSOR = RegistryChoice(processor_names, "consolidation processor")
ANSWER_POLICY = RegistryChoice(answer_policy_names, "answer policy")
EDITOR_POLICY = RegistryChoice(editor_policy_names, "editor policy")
FAMILY = RegistryChoice(family_names, "memory family")


class _ListChoice(click.ParamType):
    """A comma-separated list of registered names, or 'all'."""

    name = "names"

    def __init__(self, names: Callable[[], Iterable[str]], what: str,
                 canonical: Callable[[str], str] | None = None):
        self._names, self.what, self._canonical = names, what, canonical or (lambda v: v)

    def convert(self, value, param, ctx):
        if not isinstance(value, str):
            return value
        if value.strip().lower() == "all":
            return "all"
        got = [v.strip() for v in value.split(",") if v.strip()]
        known = list(self._names())
        bad = [v for v in got if self._canonical(v) not in known]
        if bad:
            self.fail(f"no {self.what} {bad[0]!r}; registered: {', '.join(known)}", param, ctx)
        if not got:
            self.fail(f"no {self.what} given (comma-separated names, or 'all')", param, ctx)
        return got


def _condition(name: str) -> str:
    from memora_graph.bench.conditions import get_condition
    from memora_graph.errors import MemoraError

    try:
        return get_condition(name).name  # aliases too (flat_1d_processed, memora)
    except MemoraError:
        return name


CONDITIONS = _ListChoice(condition_names, "condition", _condition)


# -- participants ------------------------------------------------------------------------------
def participants_option(default: str = "all", help: str | None = None):
    """`--participants P01,P02|all`, parsed to a list of ids, or None for all (an empty list and a
    malformed id are errors naming the option)."""
    def callback(ctx, param, value):
        from memora_graph.bank import parse_participants
        from memora_graph.errors import MemoraError

        try:
            return parse_participants(value)
        except MemoraError as exc:
            raise click.BadParameter(str(exc).removeprefix("--participants: "), ctx, param) from None

    return click.option("--participants", default=default, show_default=True, callback=callback,
                        help=help or "Comma-separated ids (P01,P02) or 'all'.")


def check_participant_option(ctx, param, value):
    """Callback of a single `--participant P01` option: an id, or a clear error."""
    if value is None:
        return value
    from memora_graph.bank import parse_participants
    from memora_graph.errors import MemoraError

    try:
        got = parse_participants(value, "--participant")
    except MemoraError as exc:
        raise click.BadParameter(str(exc).removeprefix("--participant: "), ctx, param) from None
    if got is None or len(got) != 1:
        raise click.BadParameter(f"one participant id (like P01 or alice), not {value!r}", ctx, param)
    return got[0]


# -- progress bars -----------------------------------------------------------------------------
def progress_bar(quiet: bool = False, transient: bool = False):
    """The one progress bar every long command shows (description, bar, n/m, elapsed)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    disable=quiet, transient=transient)


quiet_option = click.option("--quiet", is_flag=True, help="No progress bar.")


# -- backend options ---------------------------------------------------------------------------
backend_option_pairs = click.option(
    "-o", "--option", "options", type=(str, str), multiple=True, metavar="NAME VALUE",
    help="Any other backend option (JSON if it parses), e.g. -o structured_output json_object. Repeatable.")


def backend_options(pairs: Iterable[tuple[str, str]], **named) -> dict:
    """Backend options from the named command-line options that were given (None: not given) and
    `-o NAME VALUE` pairs, whose values are read as JSON when they parse."""
    out = {k: v for k, v in named.items() if v is not None}
    for key, value in pairs:
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


# -- output formats (rendered by memora_graph/output.py) -----------------------------------------
def output_options(f=None, *, json_help: str = ROWS_JSON):
    """--table (default) / --csv / --json / --nl, as one `fmt` argument. A command whose --json prints
    something else than rows (one object) says so in `json_help`: `@output_options(json_help=...)`."""
    if f is None:
        return functools.partial(output_options, json_help=json_help)
    for name, help_ in reversed([
        ("table", "Render a table (default)."), ("csv", "Comma-separated values."),
        ("json", json_help), ("nl", "Newline-delimited JSON, one object per line."),
    ]):
        f = click.option(f"--{name}", "fmt", flag_value=name, help=help_)(f)

    @functools.wraps(f)
    def wrapper(*args, fmt=None, **kwargs):
        return f(*args, fmt=fmt if fmt in FORMATS else "table", **kwargs)

    return wrapper
