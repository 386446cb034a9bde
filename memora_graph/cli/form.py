"""`memora remember`: write what just happened into a participant's memory (parse, call, render)."""

from __future__ import annotations

import json
import sys

import click

from memora_graph.form.checkpoint import DEFAULT_LOG_MB, DEFAULT_MOMENTS, DEFAULT_SECONDS


def checkpoint_options(f):
    """--checkpoint-mb / --checkpoint-moments / --checkpoint-seconds: the live writer's checkpoint
    schedule (memora_graph/form/checkpoint.py), for `remember` and `serve --writable`."""
    for option in reversed([
        click.option("--checkpoint-mb", type=click.FloatRange(min=0), default=DEFAULT_LOG_MB, show_default=True,
                     metavar="MB", help="Checkpoint the write-ahead log into the database file once it holds this "
                                        "many MB (a restart after a crash replays at most about this much; 0: off)."),
        click.option("--checkpoint-moments", type=click.IntRange(min=0), default=DEFAULT_MOMENTS, show_default=True,
                     metavar="N", help="... or once N moments were committed since the last checkpoint (0: off)."),
        click.option("--checkpoint-seconds", type=click.FloatRange(min=0), default=DEFAULT_SECONDS,
                     show_default=True, metavar="S",
                     help="... or once the oldest moment not checkpointed is S seconds old (0: off). A clean "
                          "close always checkpoints."),
    ]):
        f = option(f)
    return f


def checkpoint_policy(checkpoint_mb: float, checkpoint_moments: int, checkpoint_seconds: float):
    from memora_graph.form.checkpoint import CheckpointPolicy

    return CheckpointPolicy(log_mb=checkpoint_mb, moments=checkpoint_moments, seconds=checkpoint_seconds)


def _moment_or_segment(writer, obj: object, where: str):
    """A JSON object as a Moment ({video, start, end, text, id?}) or a segment record (the
    project's LayeredSegment schema: participant_id, video_id, turn_id, t_start, ...)."""
    from pydantic import ValidationError

    from memora_graph.errors import DataError
    from memora_graph.records import LayeredSegment

    if not isinstance(obj, dict):
        raise DataError(f"{where}: expected a JSON object (a narration {{video, start, end, text}} or a segment record)")
    if "video_id" in obj and "t_start" in obj:
        try:
            return LayeredSegment.model_validate(obj), obj.get("id")
        except ValidationError as exc:
            first = exc.errors()[0]
            raise DataError(f"{where}, field '{'.'.join(map(str, first['loc']))}': {first['msg']} "
                            "(a segment record in the LayeredSegment schema)") from None
    extra = sorted(set(obj) - {"video", "start", "end", "text", "id"})
    if extra:
        raise DataError(f"{where}, field '{extra[0]}': not a field of a narration (video, start, end, text, id)")
    return writer.moment(obj.get("video"), obj.get("start"), obj.get("end"), obj.get("text"), obj.get("id"), where), None


@click.command("remember")
@click.argument("bank", type=click.Path(file_okay=False))
@click.argument("text", required=False)
@click.option("--participant", required=True, help="Whose memory this is (P01). Created if the bank has no such person.")
@click.option("--video", help="The video (or episode, or session) the moment belongs to.")
@click.option("--start", type=float, help="Seconds from the start of the video.")
@click.option("--end", type=float, help="Seconds from the start of the video (default: --start).")
@click.option("--id", "key", help="The client's idempotency key (default: the video and the start time).")
@click.option("--json", "record", metavar="JSON",
              help="One moment as JSON: {\"video\", \"start\", \"end\", \"text\", \"id\"?} or a segment record "
                   "(the LayeredSegment schema, perceived elsewhere).")
@click.option("--jsonl", "stream", type=click.File("r"), metavar="FILE|-",
              help="A stream of such JSON objects, one per line ('-': stdin); each is acknowledged on stdout as "
                   "soon as it is committed.")
@checkpoint_options
def remember_cmd(bank, text, participant, video, start, end, key, record, stream, checkpoint_mb, checkpoint_moments,
                 checkpoint_seconds):
    """Remember what just happened: perceive a narration, embed it, run the online editor and commit.

    Each moment is one committed transaction: once its line is printed it survives a crash (it is
    in the write-ahead log, checkpointed into the database file on the --checkpoint-* schedule).
    The answer (one JSON line per moment) lists the editor's operations (ADD / UPDATE /
    DELETE / NOOP) with the entity ids; a moment already remembered under the same key (the
    video and start time, or --id) is answered again, marked "duplicate", and written nothing.
    Words no verb or noun class covers are kept and listed under "unknown_words".

    \b
    Examples:
      memora remember banks/home --participant P01 "put the kettle on the counter" --video kitchen-1 --start 12.5 --end 14.0
      memora remember banks/home --participant P01 --video ego4d-7 --start 3 "#C C takes a knife from the drawer"
      memora remember banks/home --participant P01 --json '{"video": "v1", "start": 3, "end": 4, "text": "open fridge"}'
      robot-narrator | memora remember banks/home --participant P01 --jsonl -
    """
    from memora_graph.errors import DataError
    from memora_graph.form.live import LiveWriter
    from memora_graph.perceive.narrations import json_lines

    given = [n for n, v in (("TEXT", text), ("--json", record), ("--jsonl", stream)) if v is not None]
    if len(given) != 1:
        raise click.UsageError("give exactly one of TEXT (with --video and --start), --json or --jsonl")
    if text is not None and (video is None or start is None):
        raise click.UsageError("TEXT needs --video and --start (seconds)")
    if text is None and any(v is not None for v in (video, start, end, key)):
        raise click.UsageError("--video, --start, --end and --id go with TEXT; --json and --jsonl carry their own")

    def emit(done) -> None:
        click.echo(json.dumps(done.as_dict(), ensure_ascii=False))
        sys.stdout.flush()

    policy = checkpoint_policy(checkpoint_mb, checkpoint_moments, checkpoint_seconds)
    with LiveWriter(bank, participant, checkpoint=policy) as writer:
        if text is not None:
            emit(writer.remember(writer.moment(video, start, start if end is None else end, text, key)))
        elif record is not None:
            try:
                obj = json.loads(record)
            except json.JSONDecodeError as exc:
                raise DataError(f"--json: not JSON ({exc.msg} at character {exc.pos})") from None
            emit(_remember(writer, obj, "--json"))
        else:
            name = "stdin" if stream.name == "<stdin>" else stream.name
            for n, obj in json_lines(stream, name, "; the rows before it were committed"):
                emit(_remember(writer, obj, f"{name}: row {n}"))


def _remember(writer, obj, where: str):
    got, key = _moment_or_segment(writer, obj, where)
    from memora_graph.form.live import Moment

    return writer.remember(got) if isinstance(got, Moment) else writer.remember_segment(got, key)
