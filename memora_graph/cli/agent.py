"""`memora ask`: parse, call `agent.ask`, render."""

from __future__ import annotations

import json

import click
import polars as pl

from memora_graph.cli.options import output_options
from memora_graph.output import render


@click.command("ask")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("question")
@click.option("--participant", required=True, help="Whose memory to ask (P01).")
@click.option("--choice", "choices", multiple=True, metavar="TEXT",
              help="An answer option (up to four; repeat). With choices the answer is one of them or "
                   "'not in memory'; without, an answer in words.")
@click.option("--memory", "family", default="memora", show_default=True, metavar="FAMILY",
              help="The memory the lookups read: memora, or a baseline's representation (flat1d, graph2d).")
@click.option("--explain", is_flag=True, help="Print the typed query the question was read as (operation, subject, "
                                               "scope, selector, relation) before the answer; with --json, under "
                                               "\"query\".")
@output_options(json_help="One JSON object: the answer, its letter, the reason, each choice's score by letter, the "
                          "evidence and the lookups made.")
def ask_cmd(bank, question, participant, choices, family, explain, fmt):
    """Ask one person's memory a question, answered by the typed reader (deterministic, no model).

    With choices, the reader picks one (or "not in memory"). Without, the answer takes the type
    the question asks for: a place (where it was last put, or is usually kept), a video and time,
    a number of times, yes or no, the next actions with their share, a routine's steps, a state
    or an activity log, or "not in memory" saying why (general knowledge, or a subject absent
    from this person's memory); with the records behind it and a confidence (a probability,
    calibrated on P01-P03). --json prints the typed answer under "typed". See docs/asking.md.

    \b
    Examples:
      memora ask banks/epic "After P03 turns on the tap, what do they usually do next?" --participant P03
      memora ask banks/epic "When P01 picks up a cup, what does that usually lead to?" --participant P01 \\
          --choice "drink water from the cup" --choice "rinse the cup" --choice "put it in the cupboard"
      memora ask banks/epic "In video P01_108, what did P01 do with the purse?" --participant P01 --json
      memora ask banks/epic "Where did P01 last put the chopping board?" --participant P01
      memora ask banks/epic "How many times did P01 open the fridge?" --participant P01 --json
      memora ask banks/epic "What was the last thing I did in P01_103?" --participant P01 --explain
    """
    from memora_graph.agent.ask import ask
    from memora_graph.agent.query import QuestionError, parse

    if len(choices) > 4:
        raise click.BadParameter("at most four choices (A-D); the reader adds 'not in memory' itself",
                                 param_hint="'--choice'")
    try:
        query = parse(question) if explain else None
    except QuestionError as exc:
        raise click.BadParameter(str(exc), param_hint="'QUESTION'") from None
    if query is not None and fmt != "json":
        click.echo(f"query: {query.brief()}")
        click.echo(query.model_dump_json(exclude_defaults=True, exclude={"text"}))
    try:
        result = ask(bank, participant, question, list(choices) or None, memory=family)
    except QuestionError as exc:
        raise click.BadParameter(str(exc), param_hint="'QUESTION'") from None
    if fmt == "json":
        out = result.as_dict()
        if query is not None:
            out["query"] = query.model_dump(mode="json", exclude_defaults=True)
        click.echo(json.dumps(out, indent=2, ensure_ascii=False))
        return
    if fmt == "table" and result.typed is not None:
        t = result.typed
        click.echo(result.answer)
        what = f"not in memory: {t.reason.replace('_', ' ')}" if not t.in_memory else f"{t.kind} answer"
        detail = f"; {t.detail}" if t.detail else ""
        click.echo(f"({what}; the question asks: {t.asked}; confidence {t.confidence:.2f}{detail})")
        if result.evidence:
            click.echo(render(pl.DataFrame(result.evidence), fmt))
        return
    if fmt == "table":
        sure = "" if result.confidence is None else f"; confidence {result.confidence:.2f}"
        click.echo(f"{result.answer}\n({result.kind} question; {result.reason}{sure})")
        if result.evidence:
            click.echo(render(pl.DataFrame(result.evidence), fmt))
        return
    rows = [{"answer": result.answer, "letter": result.letter or "", "in_memory": result.in_memory,
             "kind": result.kind, "reason": result.reason,
             "confidence": "" if result.confidence is None else result.confidence,
             "evidence": "; ".join(e["id"] for e in result.evidence)}]
    click.echo(render(pl.DataFrame(rows), fmt))


@click.command("plan")
@click.argument("bank", type=click.Path(exists=True, file_okay=False))
@click.argument("goal")
@click.option("--participant", required=True, help="Whose memory to plan from (P01).")
@click.option("--memory", "family", default="memora", show_default=True, metavar="FAMILY",
              help="The memory the lookups read: memora, or a baseline's representation (flat1d, graph2d).")
@click.option("--json", "as_json", is_flag=True, help="The structured steps (verb, object, place, preconditions, "
                                                      "evidence ids, notes) and the lookups made, as JSON.")
@click.option("--from-task/--compose", default=True, show_default=True,
              help="--from-task: start from the person's own task that does the goal (its steps on the goal's "
                   "objects, in their order, each once) when one does, else compose. --compose: always compose "
                   "from routines and episodes, as the benchmark's offline policy does (docs/planning.md).")
def plan_cmd(bank, goal, participant, family, as_json, from_task):
    """Plan a goal from one person's memory, with the offline planner (deterministic, no model).

    The planner reads the goal into actions and objects, retrieves the person's routines, episodes
    and preferences about it, and composes: a remembered procedure used as learned or transferred
    to the goal's object, procedures chained for a goal of several actions, the person's objects
    and places, their preferences inserted at the steps they govern. Each step lists the evidence
    ids it came from; an object memory has no record of is said to be "not in memory". No step
    carries a place ("put down the fridge"). A goal one of the person's tasks does ("make a cup of
    tea", "put away the groceries") is planned from that task; --compose always composes.

    \b
    Examples:
      memora plan banks/epic "make a cup of tea" --participant P30
      memora plan banks/epic "cut the cucumber" --participant P01
      memora plan banks/epic "wash, cut and stir-fry the bok choy" --participant P01 --json --compose
    """
    from memora_graph.agent.planner import plan

    result = plan(bank, participant, goal, memory=family, from_task=from_task)
    if as_json:
        click.echo(json.dumps(result.as_dict(), indent=2, ensure_ascii=False))
        return
    click.echo(f"Plan for {participant}: {result.goal}")
    for row in result.as_dict()["steps"]:
        click.echo(f"{row['n']:>2}. {row['text']}")
        extra = []
        if row.get("learned_on"):
            extra.append(row["learned_on"])
        if row.get("preference"):
            extra.append(f"preference {row['preference']}")
        if row["evidence"]:
            extra.append("evidence: " + ", ".join(row["evidence"][:4]))
        if extra:
            click.echo("    " + "; ".join(extra))
