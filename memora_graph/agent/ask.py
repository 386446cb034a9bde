"""`memora ask`: one question to one person's memory, answered by the typed reader.

    from memora_graph.agent.ask import ask
    result = ask("banks/epic", "P03", "After P03 turns on the tap, what do they usually do next?")
    result.answer, result.evidence

The same lookups and reader as the `offline` answer policy (`agent.reading`): the tools are
called directly, not through the agent loop. With choices it picks one (or "not in memory").
Without choices, over MEMORA's typed stores, the answer takes the type the question asks for
(`agent.query`): a place, a video and time, a number, yes/no, the next actions with their
share, a routine's steps, a state or an activity log, or "not in memory" with the reason
(general knowledge, or a subject absent from this person's memory), with a confidence; the
typed answer is `result.typed`. Over a baseline's representation (flat1d, graph2d) it answers
in words: the actions memory shows in the question's situation, most supported first.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from memora_graph.agent import lookups
from memora_graph.agent.confidence import load_calibration
from memora_graph.agent.query import OpenAnswer
from memora_graph.agent.query.answer import answer_open
from memora_graph.agent.evidence import events_of
from memora_graph.agent.reading import (
    OPTION_E, Event, Intent, context_windows, habit_windows, parse_question, score,
)
from memora_graph.perceive.lexicon import Lexicon
from memora_graph.retrieve.registry import get_family, tool_names, tool_set

NOT_IN_MEMORY = "not in memory"
WORDS = 3  # answers in words: at most this many actions


@dataclass
class AskResult:
    question: str
    participant: str
    answer: str  # an option's letter and text, the answer in words, or "not in memory"
    letter: str | None  # with choices: A-D, or E
    kind: str  # the question's kind (habit, preference, routine, recall)
    reason: str
    scores: list[float] = field(default_factory=list)  # with choices: one per choice, in order (A, B, ...)
    evidence: list[dict] = field(default_factory=list)  # {id, text} of the records behind the answer
    calls: list[dict] = field(default_factory=list)  # {tool, arguments}
    typed: OpenAnswer | None = None  # without choices, over MEMORA: the answer in the type asked
    probability: float | None = None  # with choices: the calibrated reader's P(the answer given is right)

    @property
    def confidence(self) -> float | None:
        return self.typed.confidence if self.typed is not None else self.probability

    @property
    def in_memory(self) -> bool:
        return self.answer != NOT_IN_MEMORY

    def as_dict(self) -> dict:
        return {"question": self.question, "participant": self.participant, "answer": self.answer,
                "letter": self.letter, "in_memory": self.in_memory, "kind": self.kind, "reason": self.reason,
                "scores": {letter: round(s, 4) for letter, s in zip("ABCD", self.scores)}, "evidence": self.evidence, "calls": self.calls,
                "confidence": self.confidence,
                "typed": self.typed.model_dump(mode="json") if self.typed is not None else None}


def _embedder():
    from memora_graph.vector_store import query_vectors

    return query_vectors().encode  # the reader's vectors, as the benchmark's offline policy has them


def _cite(ids: list[str], events: list[Event], limit: int = 8) -> list[dict]:
    text = {}
    for e in events:
        for i in e.ids:
            if e.text and i not in text:
                text[i] = e.text
    return [{"id": i, "text": text.get(i, "")} for i in list(dict.fromkeys(ids))[:limit]]


def answer_in_words(intent: Intent, events: list[Event], lex: Lexicon) -> tuple[list[str], list[str]]:
    """The actions memory shows in the question's situation, most supported first (what followed
    the trigger, for a habit; the actions around the subject otherwise), with their evidence ids."""
    windows = (habit_windows if intent.kind == "habit" else context_windows)(intent, events, lex)
    trigger = intent.trigger
    counts: Counter[tuple[str, str]] = Counter()
    ids: dict[tuple[str, str], list[str]] = {}
    for have, weight, wid in windows:
        verbs = sorted(v for k, v in have if k == "v")
        nouns = sorted(n for k, n in have if k == "n")
        for v in verbs:
            if trigger is not None and intent.kind == "habit" and v == trigger.verb:
                continue
            for n in nouns or [""]:
                counts[(v, n)] += weight
                ids.setdefault((v, n), []).extend(wid)
    best = [k for k, _ in counts.most_common(WORDS)]
    words = [f"{v} {n.split(':')[0] if ':' not in n else ' '.join(reversed(n.split(':')))}".strip().replace("_", " ")
             for v, n in best]
    return words, [i for k in best for i in ids[k][:3]]


def _check_inputs(question: str, choices: list[str] | None) -> None:
    """A question and choices within the bounds on free text (memora_graph/limits.py), or TextTooLong."""
    from memora_graph.limits import MAX_CHOICES, TextTooLong, check_text

    check_text(question, "the question")
    if choices and len(choices) > MAX_CHOICES:
        raise TextTooLong(f"{len(choices)} choices given; at most {MAX_CHOICES} (A-D)")
    for i, c in enumerate(choices or []):
        check_text(c, f"choice {chr(65 + i)}")


def ask(bank: str | Path, participant: str, question: str, choices: list[str] | None = None,
        memory: str = "memora", embed=None) -> AskResult:
    """Answer `question` from `participant`'s memory in `bank` (see the module docstring).
    `memory` picks the representation the tools read (memora, flat1d, graph2d)."""
    from memora_graph.agent.query.parse import check

    question = check(question)
    _check_inputs(question, choices)
    store = get_family(memory).open(Path(bank), participant)
    try:
        return ask_memory(store, participant, question, choices, memory, embed)
    finally:
        closer = getattr(store, "close", None)
        if closer is not None:
            closer()


def ask_memory(store, participant: str, question: str, choices: list[str] | None = None, memory: str = "memora",
               embed=None) -> AskResult:
    """`ask` over a memory already open (a `MemoryView` for "memora"), which stays open: a server
    answers many questions from one open bank. An empty or over-long question raises
    `query.QuestionError`."""
    from memora_graph.agent.query.parse import check

    question = check(question)
    _check_inputs(question, choices)
    lex = Lexicon.load()
    if not choices and memory == "memora":
        return _open(store, participant, question, lex)
    intent = parse_question(question, lex)
    names = tool_names(memory, advertised_only=False)
    tools = tool_set(memory, names, participant, store)
    calls, results = [], []
    for round_ in lookups.plan(intent, names):
        tools.prefetch(round_)
        for name, args in round_:
            calls.append({"tool": name, "arguments": args})
            results.append(tools.call(name, args))
    events = [e for r in results for e in events_of(r, lex)]
    if choices:
        opts = list(choices[:4])
        d = score(question, opts + [""] * (4 - len(opts)), events, lex, embed=embed or _embedder(),
                  calibration=load_calibration())
        if d.letter == OPTION_E:
            return AskResult(question, participant, NOT_IN_MEMORY, OPTION_E, intent.kind, d.reason, d.scores[:len(opts)],
                             _cite([i for s in d.support for i in s], events), calls, probability=d.probability)
        i = "ABCD".index(d.letter)
        return AskResult(question, participant, f"{d.letter}) {opts[i]}", d.letter, intent.kind, d.reason,
                         d.scores[:len(opts)],
                         _cite(d.support[i], events), calls, probability=d.probability)
    subject = set(intent.subject_nouns)
    if subject and not any(subject & set(e.nouns) for e in events):
        return AskResult(question, participant, NOT_IN_MEMORY, None, intent.kind, "no record of the subject",
                         calls=calls)
    words, ids = answer_in_words(intent, events, lex)
    if not words:
        return AskResult(question, participant, NOT_IN_MEMORY, None, intent.kind,
                         "no record of the situation asked about", calls=calls)
    return AskResult(question, participant, "; ".join(words), None, intent.kind, "supported", [],
                     _cite(ids, events), calls)


def _open(view, participant: str, question: str, lex: Lexicon) -> AskResult:
    """Without choices: the answer in the type the question asks for (`agent.query`)."""
    typed = answer_open(view, participant, question, lex)
    said: dict[str, list[str]] = {}
    for r in typed.records:
        said.setdefault(r.segment_id, []).append(f"{r.time_seconds:.1f}s {r.text}")
    evidence = [{"id": i, "text": "; ".join(said.get(i, []))} for i in typed.evidence[:8]]
    if not typed.in_memory:
        reason = f"{typed.reason.replace('_', ' ')}: {typed.detail}" if typed.reason else typed.detail
        return AskResult(question, participant, NOT_IN_MEMORY, None, typed.kind, reason, typed=typed)
    return AskResult(question, participant, typed.answer, None, typed.kind, typed.detail or "supported", [],
                     evidence, [{"tool": "recall", "arguments": typed.query}],
                     typed=typed)
