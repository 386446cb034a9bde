"""`memora verify`, `memora forget`, and `--no-verify` on every command that opens a bank."""

from __future__ import annotations

import logging
import os

import click

from memora_graph.cli.options import output_options
from memora_graph.output import render

SKIP_NO_VERIFY = {"verify", "forget"}


@click.command("verify")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", "participants", multiple=True, help="Only this participant (repeatable; default: all).")
@click.option("--accept", "accept_", metavar="PARTICIPANT", multiple=True,
              help="Record this participant's database as it is now (a bank built before integrity records, or a "
                   "write that did not finish), after checking in a child process that it opens. Repeatable.")
@output_options
def verify_cmd(bank, participants, accept_, fmt):
    """Check a bank deeply: per participant, the database's sha256 and size against the record of
    its last write, rows per table against the manifest, rows of other participants, write-ahead
    log or shadow files, unfinished writes or builds, staged videos; and files that belong to no
    participant. Exit status 1 if anything is wrong.

    Every command that opens a bank checks the hash first (and refuses a damaged database, a
    foreign log, an interrupted write); `--no-verify` on those commands bypasses that knowingly.

    \b
    Examples:
      memora verify banks/epic
      memora verify banks/epic --participant P01 --json
      memora verify banks/old --accept P01          # record a pre-integrity bank's P01 as it is
    """
    from memora_graph.integrity.verify import accept, verify_bank

    for p in accept_:
        rec = accept(bank, p)
        click.echo(f"{p}: recorded sha256 {rec['sha256'][:16]}..., {rec['bytes']} bytes, "
                   f"{sum(rec['tables'].values())} rows in {len(rec['tables'])} tables")
    from memora_graph.confine import mode

    report = verify_bank(bank, list(participants) or None)
    click.echo(f"ad-hoc Cypher (memora query, the cypher tool): {mode().describe()}", err=True)
    df = report.frame()
    if fmt == "table":
        click.echo(render(df.drop([c for c in ("problems", "kinds") if c in df.columns])))
        for r in report.rows:
            for line in r["problems"]:
                click.echo(f"{r['participant']}: {line}")
        for line in report.bank:
            click.echo(f"bank: {line}")
        click.echo("ok: every participant matches its record" if report.ok else "problems found (see above)")
    else:
        click.echo(render(df, fmt))
    if not report.ok:
        raise SystemExit(1)


@click.command("forget")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.option("--participant", required=True, help="Whose memory to remove (P01).")
@click.option("--dry-run", is_flag=True, help="Only list what would be removed.")
@click.option("--yes", "-y", "yes", is_flag=True, help="Remove without asking (needed when stdin is not a terminal).")
def forget_cmd(bank, participant, dry_run, yes):
    """Remove every trace of one person from a bank: their database (with its write-ahead log and
    shadow files, and so its indexes), staged videos of an unfinished build, rebuild leftovers,
    their baseline caches under BANK/.cache/ (and the embedding cache all participants share,
    which holds vectors of their texts; it is rebuilt on demand), and their manifest entry.
    Lists what it will remove and asks first (`--yes` skips the question). Exit status 1 when the
    participant is not in the bank. Run records written elsewhere (`memora bench run --out DIR`)
    are not in the bank: delete those yourself.

    \b
    Examples:
      memora forget banks/epic --participant P02 --dry-run
      memora forget banks/epic --participant P02
      memora forget banks/epic --participant P02 --yes    # no question (scripts)
    """
    import sys

    from memora_graph.bank import Bank

    b = Bank(bank)
    found = [str(p) for p in b.traces(participant)]
    if b.exists() and participant in b.manifest()["participants"]:
        found.append(f"{b.manifest_path}: entry {participant}")
    if not found:
        known = ", ".join(sorted(b.manifest()["participants"])) if b.exists() else "none"
        raise click.ClickException(f"nothing of {participant} in {bank} (the bank has: {known or 'none'})")
    if dry_run or not yes:
        for line in found:
            click.echo(f"would remove {line}")
    if dry_run:
        return
    if not yes:
        if not sys.stdin.isatty():
            raise click.ClickException(f"not removing {participant}: stdin is not a terminal, so there is no one to "
                                       "confirm; pass --yes to remove without asking")
        if not click.confirm(f"Remove every trace of {participant} from {bank}? This cannot be undone", default=False):
            raise click.ClickException(f"not confirmed: nothing of {participant} was removed")
    for line in b.forget(participant):
        click.echo(f"removed {line}")


class _StderrHandler(logging.Handler):
    """Bank notices (interrupted builds, unlisted databases) as `warning: ...` on stderr, looked
    up at emit time (click's test runner swaps the stream)."""

    def emit(self, record: logging.LogRecord) -> None:
        click.echo(f"warning: {record.getMessage()}", err=True)


def _no_verify_option() -> click.Option:
    def callback(ctx: click.Context, param, value: bool) -> None:
        from memora_graph.bank import NO_VERIFY_ENV

        if not value:
            return
        before = os.environ.get(NO_VERIFY_ENV)
        os.environ[NO_VERIFY_ENV] = "1"  # worker processes inherit it

        def restore() -> None:
            if before is None:
                os.environ.pop(NO_VERIFY_ENV, None)
            else:
                os.environ[NO_VERIFY_ENV] = before

        ctx.call_on_close(restore)

    return click.Option(["--no-verify"], is_flag=True, expose_value=False, callback=callback, is_eager=True,
                        help="Open the bank without checking each database against its recorded sha256 (and without "
                             "refusing interrupted writes or foreign logs). Knowingly: a damaged file can return wrong "
                             "results or crash. `memora verify BANK` tells what is wrong.")


def _add_no_verify(command: click.Command) -> None:
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            _add_no_verify(sub)
        return
    if command.name in SKIP_NO_VERIFY or any(p.name == "no_verify" or "--no-verify" in getattr(p, "opts", [])
                                             for p in command.params):
        return
    if any(isinstance(p, click.Argument) and p.name == "bank" for p in command.params):
        command.params.append(_no_verify_option())


def add_no_verify(command: click.Command) -> None:
    """`--no-verify` on a command taking a BANK argument (and on every such command of a group):
    the `memora` groups call it on each command they load."""
    _add_no_verify(command)


def show_bank_notices() -> None:
    """Bank notices (interrupted builds, unlisted databases) go to stderr as `warning: ...`."""
    log = logging.getLogger("memora_graph.integrity")
    if not any(isinstance(h, _StderrHandler) for h in log.handlers):
        log.addHandler(_StderrHandler())
        log.propagate = False


def register(main: click.Group) -> None:
    """Add `verify` and `forget`, and `--no-verify` to every command taking a BANK argument
    (for a group whose commands are all loaded; the `memora` groups load theirs on demand and
    call `add_no_verify` on each)."""
    main.add_command(verify_cmd, "verify")
    main.add_command(forget_cmd, "forget")
    if isinstance(main.commands.get("perf"), click.Group):
        from memora_graph.cli.perf.verify import perf_verify_cmd

        main.commands["perf"].add_command(perf_verify_cmd, "verify")
    _add_no_verify(main)
    show_bank_notices()
