"""The memory service behind `memora serve`: one bank opened read-only and kept open, its typed
retrieval tools, `ask`, the guarded ad-hoc Cypher path and the named queries, each a served tool
with a JSON schema, called with JSON arguments and answering JSON.

It knows nothing of MCP (memora_graph/serve/app.py puts it on the wire), so it can be called and
timed in process. The argument schemas are the tool registry's (memora_graph/retrieve/registry.py)
and the result schemas its result models'. Scoping: a service bound to one participant serves
only that person's memory; an unbound one requires `participant` in every call and opens that
person's database, never another's (one database per participant, read-only, checked against its
integrity record before Kùzu opens it). Nothing served writes: the views and named queries run on
read-only stores, and the Cypher tool is the read guard's (memora_graph/cypher_guard.py) path
without `--write`.
"""

from __future__ import annotations

import collections
import json
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model, field_validator

from memora_graph.bank import Bank
from memora_graph.cypher_guard import check_participant
from memora_graph.errors import BankError, MemoraError, QueryRefused
from memora_graph.limits import MAX_CHOICES, MAX_CYPHER, MAX_PARAMS, MAX_TEXT, Text
from memora_graph.queries import load_queries
from memora_graph.records import MAX_VIDEO_SECONDS
from memora_graph.retrieve.registry import MEMORA, ToolSpec, specs
from memora_graph.retrieve.search import DEFAULT_RECIPE
from memora_graph.retrieve.view import MemoryView
from memora_graph.serve.budget import DEFAULT_CALL_TIMEOUT, MAX_CALL_TIMEOUT, MAX_CALLS, Call, CallTimeout, shield
from memora_graph.store import Store

MAX_ROWS = 1000  # rows a Cypher or named query returns at most (the rest is counted, not sent)
CYPHER_BYTES = 4 * 2**20  # bytes of Arrow a cypher call's child hands back at most
CYPHER_IN_FLIGHT = 2  # cypher calls running at once (each a child process of up to 2 GB)
CYPHER_QUEUE = 8  # cypher calls waiting beyond those; past it a call is refused as busy
CYPHER_TIMEOUT = 30.0
MAX_CYPHER_TIMEOUT = 300.0
# A writable server's readers (the tools' view, the named queries) run each Kùzu query on one thread, so
# that a remember committing meanwhile keeps a core: on 2 cores at 1,000 h, a remember's p95 while
# tools were called back to back was 68-81 ms with Kùzu's default (every core), 42-51 ms with one
# (docs/findings/live-remember-latency-1000h.md).
READER_THREADS = 1
QUERY_PREFIX = "query_"  # a named query `object_history` is served as the tool `query_object_history`
PENDING_MAX = 256  # committed moments queued for the readers before the writer folds them in itself, if no reader is busy
SEGMENT_BYTES = 200_000  # JSON of one `remember` segment record at most
SPIN_ENV = "MEMORA_TEST_SPIN_TOOL"  # test only: also serve `test_spin`, a call that runs in Python for as long as asked


class UnknownTool(MemoraError):
    """A call to a tool this server does not have."""


class ArgumentError(MemoraError):
    """Arguments refused before the tool runs; `problems` names each field at fault."""

    def __init__(self, tool: str, problems: list[tuple[str, str]]):
        self.tool = tool
        self.problems = problems
        super().__init__(f"{tool}: invalid arguments (" + "; ".join(f"{f}: {m}" for f, m in problems) + ")")

    def fields(self) -> list[dict[str, str]]:
        return [{"field": f, "message": m} for f, m in self.problems]


@dataclass(frozen=True)
class Endpoint:
    """One served tool: what a client lists, and how a call is answered."""

    name: str
    description: str
    args: type[BaseModel]  # validates the arguments (participant aside)
    input_schema: dict[str, Any]
    output_schema: dict[str, Any] | None
    kind: str  # retrieval, ask, recall, plan, cypher, query, remember
    run: Callable[[str, dict[str, Any]], dict[str, Any]]  # (participant, validated arguments) -> JSON result
    stoppable: bool = True  # past its budget its work is stopped (a remember's commit is left to finish)


# -- argument and result models of the tools this module adds ------------------------------------

class _Args(BaseModel):
    model_config = ConfigDict(extra="forbid")


class AskArgs(_Args):
    question: str = Field(min_length=1, max_length=MAX_TEXT, description="The question, in words (e.g. 'After P03 turns on the tap, "
                                                     "what do they usually do next?').")
    choices: list[Text] | None = Field(None, max_length=MAX_CHOICES, description="Up to four answer options (A-D). With them "
                                      "the answer is one of them or 'not in memory'; without, an answer in words.")


class CypherArgs(_Args):
    query: str = Field(min_length=1, max_length=MAX_CYPHER, description="One read-only Cypher statement (MATCH ... RETURN ...). $participant "
                                                 "is bound to the participant served. Writes, files, extensions, other "
                                                 "databases and schema statements are refused.")
    params: dict[str, Any] = Field(default_factory=dict, max_length=MAX_PARAMS,
                                   description="Values of the statement's other $parameters.")
    timeout: float = Field(CYPHER_TIMEOUT, gt=0, le=MAX_CYPHER_TIMEOUT, allow_inf_nan=False,
                           description="Seconds before the query is stopped.")


class SpinArgs(_Args):
    seconds: float = Field(ge=0, le=600, allow_inf_nan=False)


class EvidenceItem(BaseModel):
    id: str
    text: str


class LookupCall(BaseModel):  # one lookup behind an answer or a plan (not agent.ToolCall, a parsed model call)
    tool: str
    arguments: dict[str, Any]


class AskAnswer(BaseModel):
    question: str
    participant: str
    answer: str = Field(description="An option's letter and text, the answer in words, or 'not in memory'.")
    letter: str | None
    in_memory: bool
    kind: str = Field(description="With choices, the question's kind (habit, preference, routine or recall); "
                                  "without, the answer's type (place, time, count, yesno, next, routine, state, "
                                  "activity, actions, not_in_memory).")
    reason: str
    scores: dict[str, float] = Field(description="With choices: each choice's score, by its letter (A, B, ...).")
    evidence: list[EvidenceItem] = Field(description="The records behind the answer.")
    calls: list[LookupCall] = Field(description="The typed lookups the reader made.")
    confidence: float | None = Field(None, description="The probability that the answer is right (with choices: "
                                                            "the calibrated reader's, for the letter given).")
    typed: dict[str, Any] | None = Field(None, description="Without choices: the answer in the type asked (a place, "
                                                           "a video and time, a count, yes/no, next actions with "
                                                           "their share, steps, states; or the not-in-memory reason).")


class PlanArgs(_Args):
    goal: str = Field(min_length=1, max_length=MAX_TEXT, description="The goal, in words (e.g. 'cut the cucumber', 'wash, cut and "
                                                 "stir-fry the bok choy').")


class PlanStep(BaseModel):
    n: int
    text: str
    verb: str
    object: str
    place: str
    preconditions: list[str]
    evidence: list[str] = Field(description="Ids of the routines, episodes, objects and preferences the step came from.")
    grounded: bool | None = None
    source: str | None = None
    note: str | None = Field(None, description="What memory lacks for the step (e.g. 'no cucumber in memory').")
    learned_on: str | None = None
    preference: str | None = None
    verb_class: str | None = None


class PlanAnswer(BaseModel):
    goal: str
    participant: str
    steps: list[PlanStep]
    calls: list[LookupCall] = Field(description="The typed lookups the planner made.")


class RememberArgs(_Args):
    text: str | None = Field(None, min_length=1, max_length=2000,
                             description="What just happened, in words (e.g. 'put the kettle on the counter', or Ego4D "
                                         "style '#C C takes a knife from the drawer'). Give this or `segment`.")
    video: str | None = Field(None, min_length=1, max_length=200,
                              description="The video, episode or session the moment belongs to (with `text`).")
    start: float | None = Field(None, ge=0, le=MAX_VIDEO_SECONDS, allow_inf_nan=False,
                                description="Seconds from the start of the video (at most 86400: 24 h).")
    end: float | None = Field(None, ge=0, le=MAX_VIDEO_SECONDS, allow_inf_nan=False,
                              description="Seconds from the start (default: start).")
    id: str | None = Field(None, min_length=1, max_length=200,
                           description="Idempotency key: a retried call with the same key (default: video and start) "
                                       "returns its first answer and writes nothing.")
    segment: dict[str, Any] | None = Field(None, max_length=64, description="Instead of text: a segment record "
                                           "perceived elsewhere (the project's LayeredSegment schema; at most "
                                           f"{SEGMENT_BYTES // 1000} kB of JSON).")

    @field_validator("segment")
    @classmethod
    def _bounded(cls, value: dict[str, Any] | None) -> dict[str, Any] | None:
        if value is not None and len(json.dumps(value, default=str)) > SEGMENT_BYTES:
            raise ValueError(f"more than {SEGMENT_BYTES // 1000} kB of JSON; a segment record is a few kB")
        return value


class EditOpResult(BaseModel):
    id: str
    op: str = Field(description="ADD, UPDATE, DELETE or NOOP.")
    entity: str
    object: str
    reason: str
    changes: dict[str, str]
    merged_into: str | None = None


class RememberResult(BaseModel):
    key: str
    participant: str
    segment: str = Field(description="The activity record written (or found, for a duplicate).")
    video: str
    turn: int
    ops: list[EditOpResult] = Field(description="The online editor's decisions, with the entity ids they wrote.")
    duplicate: bool = Field(description="True when the key was remembered before: nothing was written now.")
    unknown_words: list[str] = Field(description="Words no verb or noun class covers (kept in the text).")


class Rows(BaseModel):
    participant: str
    columns: list[str]
    rows: list[dict[str, Any]]
    row_count: int = Field(description="Rows the query returned (rows holds at most the first max_rows).")
    truncated: bool


def _schema(model: type[BaseModel]) -> dict[str, Any]:
    """An argument model's JSON schema in the registry's style (titles dropped), with
    `additionalProperties: false` (unknown arguments are refused, not ignored)."""
    params = model.model_json_schema()
    props = {k: {kk: vv for kk, vv in v.items() if kk != "title"} for k, v in params.get("properties", {}).items()}
    out: dict[str, Any] = {"type": "object", "properties": props, "required": list(params.get("required", [])),
                           "additionalProperties": False}
    if "$defs" in params:
        out["$defs"] = params["$defs"]
    return out


def _problems(exc: ValidationError) -> list[tuple[str, str]]:
    return [(".".join(map(str, e["loc"])) or "arguments", e["msg"]) for e in exc.errors()]


def _rows(frame, participant: str, max_rows: int, total: int | None = None) -> dict[str, Any]:
    """A polars frame as JSON rows (dates as ISO text, as polars writes them). `total`: the rows
    the query returned, where `frame` already holds only the first ones."""
    head = frame.head(max_rows)
    rows = json.loads(head.write_json()) if head.height else []
    total = frame.height if total is None else total
    return Rows(participant=participant, columns=list(frame.columns), rows=rows, row_count=total,
                truncated=total > head.height).model_dump(mode="json")


class Busy(MemoraError):
    """Too many calls (or cypher calls) at once: the call was not run."""


class _Guard:
    """A participant's lock (calls that read a view take it: a view and its Kùzu connection are
    not shared across threads), knowing which thread holds it, so that a call stopped past its
    budget interrupts the Kùzu query only while it is the one running it. Taken as
    `with guard.lock, guard.owned():`: the lock's own `__enter__` is C code, where no StopCall
    lands (serve/budget.py), so a stop can never leave it taken."""

    def __init__(self, lock: threading.Lock):
        self.lock = lock
        self.owner: int | None = None
        self._meta = threading.Lock()

    def owned(self) -> _Owned:
        return _Owned(self)

    def interrupt_if_held_by(self, thread_id: int | None, interrupt: Callable[[], None]) -> None:
        with self._meta:
            if thread_id is not None and self.owner == thread_id:
                interrupt()


class _Owned:
    def __init__(self, guard: _Guard):
        self.guard = guard

    def __enter__(self) -> None:
        self.guard.owner = threading.get_ident()

    def __exit__(self, *exc) -> None:
        with self.guard._meta:
            self.guard.owner = None


class MemoryService:
    """A bank kept open for many calls. `participant` binds every call to one person; without it,
    each call names one. Thread-safe: calls that read a view take one lock (a view and its Kùzu
    connection are not shared across threads); Cypher runs in its own child process."""

    def __init__(self, bank: str | Path, participant: str | None = None, recipe: str = DEFAULT_RECIPE,
                 max_rows: int = MAX_ROWS, unconfined_cypher: bool = False, cypher_in_flight: int = CYPHER_IN_FLIGHT,
                 cypher_queue: int = CYPHER_QUEUE, writable: bool = False, consolidate_every: int | None = None,
                 call_timeout: float | None = DEFAULT_CALL_TIMEOUT, max_calls: int = MAX_CALLS, checkpoint=None):
        """`unconfined_cypher`: offer the cypher tool even where the kernel cannot confine its
        child process (memora_graph/confine.py); by default it is offered only where it can.
        `writable` (one participant only) also serves the `remember` tool: this process then
        holds the participant's live writer (form/live.py); reads go to the persisted tool stores
        computed from the database as the writer opened it (written first if stale) and, for what
        a remember or a consolidation changed since, to the writer's own store (`MemoryView.live`,
        `absorb`), so the next call sees what was just remembered (no other process can
        open the database meanwhile: Kùzu locks it, so no confined child can either, and the cypher
        tool is then offered only with `unconfined_cypher`). `consolidate_every`: after that many
        new segments, incremental consolidation runs in a background thread (consolidate/live.py).
        `call_timeout`: seconds a call may run before it is answered CallTimeout and its work is
        stopped (serve/budget.py; None: no budget, the call runs in the caller's thread);
        `max_calls`: calls in flight at once, past which a call is refused as Busy.
        `checkpoint`: the writer's checkpoint schedule (a form/checkpoint.py `CheckpointPolicy`;
        default: its defaults)."""
        from memora_graph.confine import mode

        self.writer = None
        self.consolidator = None
        self._lock = threading.Lock()
        self._named_lock = threading.Lock()  # the named queries' own connection (a writable server's)
        self._named_reader = None
        self._pending: collections.deque = collections.deque()  # committed, not yet in the readers' caches
        # set below; the writer's open may already commit moments it re-applies (`_absorb`)
        self._guards: dict[str, _Guard] = {}
        self._views: dict[str, MemoryView] = {}
        if writable:
            if participant is None:
                raise BankError("a writable server serves one participant's memory: name it (--participant P01)")
            from memora_graph.form.live import LiveWriter

            participant = check_participant(participant, "--participant")
            # creates the bank or the participant if need be; perceives and embeds outside the readers' lock,
            # and commits and updates the readers' caches inside it
            # the readers read through a connection of their own and take each committed moment in at
            # their next call (`_catch_up`): a remember never waits for a reader, nor a reader for a commit
            self.writer = LiveWriter(bank, participant, on_commit=self._absorb, checkpoint=checkpoint,
                                     readers_apart=True)
        elif consolidate_every is not None:
            raise BankError("--consolidate-every applies to a --writable server")
        self.bank = Bank(bank)
        self.bank.manifest()  # a missing or damaged bank fails here, naming the file
        self.participants = self.bank.participants()
        if participant is not None:
            participant = check_participant(participant, "--participant")
            if self._unknown(participant):
                raise BankError(f"{self.bank.path}: {self._unknown(participant)}")
        self.participant = participant
        self.recipe = recipe
        self.max_rows = max_rows
        self.confinement = mode()
        # a writable server holds the database open, so Cypher could only run in this process, unconfined
        self.cypher_offered = (self.confinement.confined and self.writer is None) or unconfined_cypher
        self._cypher_slots = threading.BoundedSemaphore(cypher_in_flight)
        self._cypher_waiting = 0
        self._cypher_bound = cypher_in_flight + cypher_queue
        self._cypher_count = threading.Lock()
        if call_timeout is not None and not (0 < call_timeout <= MAX_CALL_TIMEOUT):
            raise BankError(f"--call-timeout must be above 0 and at most {MAX_CALL_TIMEOUT:.0f} seconds")
        self.call_timeout = call_timeout
        self._max_calls, self._in_flight, self._in_flight_lock = max_calls, 0, threading.Lock()
        # one lock per participant (a writable server's one participant: the writer's lock)
        self._guards = {p: _Guard(self._lock if self.writer is not None else threading.Lock())
                        for p in ([participant] if participant is not None else self.participants)}
        self._endpoints = {e.name: e for e in self._build_endpoints()}
        if self.writer is not None and consolidate_every is not None:
            from memora_graph.consolidate.live import BackgroundConsolidation

            self.consolidator = BackgroundConsolidation(self.writer, every=consolidate_every, lock=self.write_locks(),
                                                        on_done=self._consolidated)
        if participant is not None:
            self.warm(participant)  # a damaged database is refused now, before the first call

    # -- participants and views ------------------------------------------------------------------
    def _unknown(self, participant: str) -> str | None:
        if participant not in self.participants:
            return f"{participant} is not in this bank (has: {', '.join(self.participants) or 'none'})"
        return None

    def _view(self, participant: str) -> MemoryView:
        """The participant's memory, opened read-only (integrity checked) on first use and kept."""
        view = self._views.get(participant)
        if view is None:
            with shield():  # an open is never cut halfway by a call's budget (serve/budget.py)
                if self.writer is None:
                    view = self._open_view(participant)
                else:
                    with self.writer.write_lock:  # no commit while it reads: it holds every one before
                        view = self._open_view(participant)
                        self._pending.clear()
        if self.writer is not None:
            self._catch_up(view)
        return view

    def _catch_up(self, view: MemoryView) -> None:
        """Take in what was committed since this view last read (called under the readers' lock,
        at the start of each call): the remembered moments, a consolidation's new records."""
        while self._pending:
            kind, delta = self._pending.popleft()
            if kind == "moment":
                view.absorb(delta)
            else:
                view.reload_inferred()

    def _open_view(self, participant: str) -> MemoryView:
        if self.writer is not None:
            # the persisted tool stores, if computed from the database as the writer opened it (and
            # nothing was written since: the view could not absorb it), else the writer's store
            sha = self.writer.opened_sha256 if self.writer.commits == 0 else None
            # a connection of the view's own on the writer's database (the last committed snapshot):
            # a remember's commit runs beside the readers, who wait only while their caches take it in
            reader = self.writer.store.reader(counted=False, threads=READER_THREADS)
            try:
                view = self._views[participant] = MemoryView.live(reader, self.bank.path, participant, sha,
                                                                  config=self.recipe, own=True)
            except BaseException:
                reader.close()
                raise
        else:
            view = self._views[participant] = MemoryView.open(self.bank.path, participant, config=self.recipe)
        return view

    def warm(self, participant: str) -> None:
        """Open a participant's memory and load what every call reads (tables, vectors, the query
        encoder), so that the first call costs what later ones do."""
        with self._guards[participant].lock, self._guards[participant].owned():
            view = self._view(participant)
            view.warm()
            view.embed("warm up the query encoder")

    def close(self) -> None:
        if self.consolidator is not None:
            self.consolidator.stop()
        with self._named_lock:
            if self._named_reader is not None:
                self._named_reader.close()
                self._named_reader = None
        for participant, guard in self._guards.items():
            # a call stuck in one long C call past its budget still holds its lock: its view is left open
            if guard.lock.acquire(timeout=5.0):
                try:
                    view = self._views.pop(participant, None)
                    if view is not None:
                        view.close()
                    if self.writer is not None:
                        self.writer.close()
                finally:
                    guard.lock.release()

    def _discard(self, participant: str) -> None:
        """Drop a participant's open view (after a call was stopped inside it, its caches may be
        half-filled): the next call opens it afresh."""
        with self._guards[participant].lock, self._guards[participant].owned():
            view = self._views.pop(participant, None)
            if view is not None:
                view.close()

    def _interrupt(self, participant: str, thread_id: int | None) -> None:
        """Interrupt the Kùzu query of the call running in `thread_id`, if it holds the view now."""
        view = self._views.get(participant)
        if view is not None:
            self._guards[participant].interrupt_if_held_by(thread_id, view.interrupt)

    def __enter__(self) -> MemoryService:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the served tools ------------------------------------------------------------------------
    def _participant_schema(self) -> dict[str, Any]:
        return {"type": "string", "enum": list(self.participants),
                "description": "Whose memory to read (one participant id of this bank); calls never see another's."}

    def _endpoint(self, name: str, description: str, args: type[BaseModel], output: dict | None, kind: str,
                  run: Callable[[str, dict[str, Any]], dict[str, Any]], schema: dict | None = None) -> Endpoint:
        schema = dict(schema or _schema(args))
        if self.participant is None:
            schema["properties"] = {"participant": self._participant_schema(), **schema["properties"]}
            schema["required"] = ["participant", *schema["required"]]
        else:
            description = f"{description} (Memory of {self.participant}.)"
        # a remember's commit is left to finish; a confined cypher call is a child process under its own
        # time limit (capped at the budget), killed by adhoc.py: its waiting thread is not interrupted
        stoppable = kind != "remember" and not (kind == "cypher" and self.writer is None)
        return Endpoint(name, description, args, schema, output, kind, run, stoppable)

    def _build_endpoints(self) -> list[Endpoint]:
        out = []
        for spec in specs(MEMORA):  # the registry's schema, as agents get it (`memora tools --json`)
            registry = {**spec.schema()["function"]["parameters"], "additionalProperties": False}
            out.append(self._endpoint(spec.name, spec.description, spec.args,
                                      spec.result.model_json_schema(mode="serialization"), "retrieval",
                                      self._retrieval(spec), registry))
        out.append(self._endpoint(
            "ask", "Ask the person's memory a question, answered by the typed reader (deterministic, no model): it "
                   "makes the typed lookups the question needs and answers with the records behind the answer, or "
                   "'not in memory'. Without choices the answer takes the type asked (a place, a video and time, a "
                   "count, yes/no, next actions with their share, routine steps, a state) under `typed`, with a "
                   "confidence; 'not in memory' says why (general knowledge, or a subject absent from this memory).",
            AskArgs, AskAnswer.model_json_schema(mode="serialization"), "ask", self._ask))
        out.append(self._recall_endpoint())
        out.append(self._endpoint(
            "plan", "Plan a goal from the person's memory with the offline planner (deterministic, no model): "
                    "remembered procedures used or transferred to the goal's objects, chained, with the person's "
                    "objects, places and preferences; each step with its evidence ids.",
            PlanArgs, PlanAnswer.model_json_schema(mode="serialization"), "plan", self._plan))
        if self.cypher_offered:  # only where the kernel confines its child, unless started --unconfined-cypher
            out.append(self._endpoint(
                "cypher", "Run one read-only Cypher statement on the person's memory graph (schema: `memora queries`, "
                          "schema/*.cypher). Writes, file access, extensions and other databases are refused; at most "
                          f"{self.max_rows} rows come back.",
                CypherArgs, Rows.model_json_schema(mode="serialization"), "cypher", self._cypher))
        if self.writer is not None:
            out.append(self._endpoint(
                "remember", "Remember what just happened: a narration (text, video, start, end) or a segment record is "
                            "perceived (offline, deterministic), embedded, edited into the memory (ADD / UPDATE / DELETE "
                            "/ NOOP per object) and committed before the answer; the next call reads it. Idempotent by "
                            "`id` (default: video and start).",
                RememberArgs, RememberResult.model_json_schema(mode="serialization"), "remember", self._remember))
        if os.environ.get(SPIN_ENV):  # test only: a call as slow as asked, in Python, holding the view
            out.append(self._endpoint("test_spin", "Test only: run in Python for `seconds`, holding the view.",
                                      SpinArgs, None, "test", self._spin))
        for q in load_queries().values():
            if q.name.startswith("_") or q.writes or "participant" not in q.params:
                continue
            fields = {p: (str, Field(max_length=MAX_TEXT, description=f"The query's ${p} (`memora queries`)."))
                      for p in q.params if p != "participant"}
            args = create_model(f"{q.name}_args", __base__=_Args, **fields)
            out.append(self._endpoint(QUERY_PREFIX + q.name, f"Named query {q.name}: {q.description}", args,
                                      Rows.model_json_schema(mode="serialization"), "query", self._named(q.name)))
        return out

    def endpoints(self) -> list[Endpoint]:
        return list(self._endpoints.values())

    def slow(self, name: str) -> bool:
        """Whether a call may take seconds (Cypher runs in a child process under a time limit)."""
        endpoint = self._endpoints.get(name)
        return endpoint is not None and endpoint.kind == "cypher"

    def _retrieval(self, spec: ToolSpec) -> Callable[[str, dict[str, Any]], dict[str, Any]]:
        def run(participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
            with self._guards[participant].lock, self._guards[participant].owned():
                return spec.fn(self._view(participant), **arguments).as_json()
        return run

    def _ask(self, participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
        from memora_graph.agent.ask import ask_memory

        with self._guards[participant].lock, self._guards[participant].owned():
            view = self._view(participant)
            result = ask_memory(view, participant, arguments["question"], arguments["choices"])
            self._built(view, "ask")
        return AskAnswer.model_validate(result.as_dict()).model_dump(mode="json")

    def _recall_endpoint(self) -> Endpoint:
        """`recall`: the typed query (agent/query/model.py) answered directly, no words parsed."""
        from memora_graph.agent.query import OpenAnswer, Query

        return self._endpoint(
            "recall", "Recall from the person's memory with a typed query instead of words (deterministic, no model): "
                      "an operation (where, when, which_video, count, exists, list, next, previous, steps, state, "
                      "duration) on a subject (verb and objects, in EPIC classes or the person's own words), inside a "
                      "scope (videos, a time window, before / after an event, the nth or last session), picked by a "
                      "selector (first, last, nth, usual, all), optionally related to an anchor event (before, after, "
                      "while, instead_of). The answer is typed (a place, a video and time, a count, yes/no, actions "
                      "with shares, steps, states, a log, seconds) with evidence ids and a confidence; a combination "
                      "that makes no sense is answered with reason 'invalid_query' and why. Example: "
                      '{"operation": "count", "subject": {"verb": "open", "objects": ["fridge"]}, '
                      '"scope": {"videos": ["P01_103"]}}.',
            Query, OpenAnswer.model_json_schema(mode="serialization"), "recall", self._recall)

    def _recall(self, participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
        from memora_graph.agent.query import recall

        with self._guards[participant].lock, self._guards[participant].owned():
            view = self._view(participant)
            answer = recall(view, participant, arguments)
            self._built(view, "recall")
        return answer.model_dump(mode="json")

    def _plan(self, participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
        from memora_graph.agent.planner import plan_memory

        with self._guards[participant].lock, self._guards[participant].owned():
            view = self._view(participant)
            result = plan_memory(view, participant, arguments["goal"])
            self._built(view, "plan")
        return PlanAnswer.model_validate(result.as_dict()).model_dump(mode="json")

    @staticmethod
    def _built(view: MemoryView, kind: str) -> None:
        """After a view's first ask, recall or plan: what it built for the next ones (the action log,
        the vocabulary, the planner's tables) joins what `warm` kept from the cyclic collector
        (`MemoryView.freeze_loaded`): walked by every full collection, it cost the call a full
        collection fell in (at 1,000 h, plan's p95 351-376 ms before, 193-206 ms after)."""
        done = view.__dict__.setdefault("_serve_built", set())
        if kind not in done:
            done.add(kind)
            view.freeze_loaded()

    def _remember(self, participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
        seg, text = arguments.get("segment"), arguments.get("text")
        if (seg is None) == (text is None):
            raise ArgumentError("remember", [("text", "give the narration `text` (with video and start), or `segment`")])
        if text is not None and (arguments.get("video") is None or arguments.get("start") is None):
            missing = [f for f in ("video", "start") if arguments.get(f) is None]
            raise ArgumentError("remember", [(f, "required with text") for f in missing])
        if seg is not None:
            from memora_graph.records import LayeredSegment

            try:
                seg = LayeredSegment.model_validate(seg)
            except ValidationError as exc:
                raise ArgumentError("remember", [(f"segment.{f}", m) for f, m in _problems(exc)]) from None
        if seg is not None:
            done = self.writer.remember_segment(seg, arguments.get("id"))
        else:
            start = arguments["start"]
            end = start if arguments.get("end") is None else arguments["end"]
            done = self.writer.remember(self.writer.moment(arguments["video"], start, end, text, arguments.get("id"),
                                                           where="remember"))
        if self.consolidator is not None and not done.duplicate:
            self.consolidator.added(1)
        return RememberResult.model_validate(done.as_dict()).model_dump(mode="json")

    def write_locks(self):
        """What another writer through the writer's store (a background consolidation) holds
        around its write: the writer's lock (no remember's transaction runs meanwhile on that
        connection). The readers take its records in at their next call (`_consolidated`)."""
        return self.writer.write_lock

    def _absorb(self, delta: dict) -> None:
        """Right after a remember committed (the writer's thread, holding its lock): queued for
        the readers, who take it in at their next call (`_catch_up`). A long stream with no read
        is folded in every PENDING_MAX moments, when no reader holds the view (never waiting for
        one), so the queue stays bounded without a remember waiting on a reader."""
        self._pending.append(("moment", delta))
        if len(self._pending) >= PENDING_MAX:
            guard = self._guards.get(self.writer.participant)
            view = self._views.get(self.writer.participant)
            if guard is not None and view is not None and guard.lock.acquire(blocking=False):
                try:
                    self._catch_up(view)
                finally:
                    guard.lock.release()

    def _consolidated(self) -> None:
        """After a background consolidation committed (holding the writer's lock): the readers
        load the new records at their next call; a later open takes them in from the journal."""
        self.writer.journal.note_inferred()  # (form/live_journal.py)
        self._pending.append(("inferred", None))

    def _cypher(self, participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
        from memora_graph.adhoc import run_query

        from memora_graph.cypher_guard import for_agents

        if self.writer is not None:  # offered only --unconfined-cypher: no other process can open the database
            from memora_graph.adhoc import bind_params
            from memora_graph.cypher_guard import check_query

            try:
                statement = check_query(arguments["query"], write=False)
                params = bind_params(statement, arguments["params"], participant)
            except QueryRefused as exc:
                raise QueryRefused(for_agents(str(exc))) from None
            with self._named_lock:  # the named queries' connection (the last committed snapshot)
                store = self._named_store()
                store.set_timeout(self._cypher_timeout(arguments["timeout"]))
                try:
                    frame = store.query(statement.text, params)
                finally:
                    store.set_timeout(None)
            return _rows(frame, participant, self.max_rows)

        # the guarded ad-hoc path of `memora query`, read-only, on this participant's database only
        # (a `participant` parameter that names someone else is refused there)
        # at most CYPHER_IN_FLIGHT children at once, CYPHER_QUEUE more calls waiting; past that, busy
        with self._cypher_count:
            if self._cypher_waiting >= self._cypher_bound:
                raise Busy(f"busy: {self._cypher_bound} cypher calls are already running or waiting; retry in a "
                           "few seconds")
            self._cypher_waiting += 1
        try:
            with self._cypher_slots:
                result = run_query(self.bank.path, arguments["query"], arguments["params"], participant=participant,
                                   write=False, timeout=self._cypher_timeout(arguments["timeout"]),
                                   max_rows=self.max_rows,
                                   max_bytes=CYPHER_BYTES)
        except QueryRefused as exc:
            raise QueryRefused(for_agents(str(exc))) from None
        finally:
            with self._cypher_count:
                self._cypher_waiting -= 1
        return _rows(result.frame, participant, self.max_rows, result.total_rows)

    def _cypher_timeout(self, asked: float) -> float:
        """A cypher call's time limit: its `timeout`, at most the call's budget."""
        return asked if self.call_timeout is None else min(asked, self.call_timeout)

    def _spin(self, participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
        import time

        with self._guards[participant].lock, self._guards[participant].owned():
            self._view(participant)
            end, n = time.monotonic() + arguments["seconds"], 0
            while time.monotonic() < end:  # pure Python, holding the GIL as a parser's loop would
                n += 1
        return {"spins": n}

    def _named_store(self) -> Store:
        """A writable server's connection for named queries and Cypher (short queries only; opened
        on first use, under `_named_lock`), on the writer's database like the view's."""
        if self._named_reader is None:
            self._named_reader = self.writer.store.reader(counted=False, threads=READER_THREADS)
        return self._named_reader

    def _named(self, name: str) -> Callable[[str, dict[str, Any]], dict[str, Any]]:
        def run(participant: str, arguments: dict[str, Any]) -> dict[str, Any]:
            if self.writer is not None:
                # a second connection on the writer's database (Kùzu serves it the last committed
                # snapshot): a named query that scans the memory for seconds does not hold the
                # readers' lock, so remembers and the other tools do not wait for it
                with self._named_lock:
                    frame = self._named_store().run(name, participant=participant, **arguments)
                return _rows(frame, participant, self.max_rows)
            with self._guards[participant].lock, self._guards[participant].owned():
                frame = self._view(participant).store.run(name, participant=participant, **arguments)
            return _rows(frame, participant, self.max_rows)
        return run

    # -- calls -----------------------------------------------------------------------------------
    def resolve(self, name: str, arguments: dict[str, Any] | None) -> tuple[Endpoint, str, dict[str, Any]]:
        """The tool, the participant and the validated arguments of a call, or ArgumentError
        naming every field at fault (UnknownTool for a tool this server does not have)."""
        endpoint = self._endpoints.get(name)
        if endpoint is None:
            raise UnknownTool(f"no tool {name!r}; tools: {', '.join(self._endpoints)}")
        if arguments is not None and not isinstance(arguments, dict):
            raise ArgumentError(name, [("arguments", "must be an object")])
        arguments = dict(arguments or {})
        problems: list[tuple[str, str]] = []
        given = arguments.pop("participant", None)
        participant = self.participant
        if participant is not None:
            if given is not None and given != participant:
                problems.append(("participant", f"this server serves only {participant}'s memory, not {given!r}"))
        elif given is None:
            problems.append(("participant", "required: whose memory to read (one of "
                                            f"{', '.join(self.participants)})"))
        else:
            try:
                participant = check_participant(given, "participant")
            except QueryRefused as exc:
                problems.append(("participant", str(exc)))
            else:
                if self._unknown(participant):
                    problems.append(("participant", self._unknown(participant)))
        try:
            validated = endpoint.args.model_validate(arguments).model_dump()
        except ValidationError as exc:
            problems += _problems(exc)
        if problems:
            raise ArgumentError(name, problems)
        return endpoint, participant, validated

    def start(self, name: str, arguments: dict[str, Any] | None = None,
              on_done: Callable[[], None] | None = None) -> Call:
        """Start one call in a thread of its own (serve/budget.py) after validating it: UnknownTool,
        ArgumentError, or Busy past `max_calls` in flight, raised before anything runs. `on_done()`
        runs in the call's thread once it has finished (or been stopped). The caller waits for it
        up to `call_timeout`, then `call.stop()`s it: see `call`."""
        endpoint, participant, validated = self.resolve(name, arguments)
        with self._in_flight_lock:
            if self._in_flight >= self._max_calls:
                raise Busy(f"busy: {self._max_calls} calls are already running; retry in a few seconds")
            self._in_flight += 1

        def done() -> None:
            with self._in_flight_lock:
                self._in_flight -= 1
            if on_done is not None:
                on_done()

        call = Call(lambda: endpoint.run(participant, validated), stoppable=endpoint.stoppable,
                    interrupt=lambda: self._interrupt(participant, call.thread_id),
                    after_stop=lambda: self._discard(participant) if call.injected else None,
                    on_done=done, name=f"memora-{name}")
        try:
            return call.start()
        except RuntimeError as exc:  # no thread to be had (the process's limit)
            with self._in_flight_lock:
                self._in_flight -= 1
            raise Busy(f"busy: cannot start the call ({exc}); retry in a few seconds") from None

    def timed_out(self, call: Call, name: str) -> CallTimeout:
        """Stop a call past its budget; the error its caller gets."""
        call.stop()
        finish = ("its work was stopped" if call.stoppable else
                  "it is left to finish (a remember may still be committed: retrying with the same id writes it "
                  "once)" if name == "remember" else "its query is stopped at the time limit")
        return CallTimeout(f"{name}: took too long: no answer within {self.call_timeout:g} s (the server's "
                           f"--call-timeout); {finish}. Narrow the request, or retry later if the server is busy")

    def call(self, name: str, arguments: dict[str, Any] | None = None) -> dict[str, Any]:
        """Answer one call: the tool's JSON result. Raises UnknownTool or ArgumentError before
        anything runs, Busy, CallTimeout past `call_timeout` (its work then stopped), and
        ToolError / QueryRefused / BankError / StoreError (MemoraError) for a call the tool
        cannot answer."""
        if self.call_timeout is None:
            endpoint, participant, validated = self.resolve(name, arguments)
            return endpoint.run(participant, validated)
        call = self.start(name, arguments)
        if not call.wait(self.call_timeout):
            raise self.timed_out(call, name)
        return call.result()
