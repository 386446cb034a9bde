"""Run offline consolidation + enrichment for one participant and store the inferred knowledge.

Flow: load the memory slice -> consolidation per completed video -> participant consolidation ->
enrichment -> drop any cited id that is not in the bank -> retrieval text + embeddings ->
Routine / Preference nodes with SUPPORTED_BY / USES / ABOUT edges. The participant's previous
inferred knowledge is deleted and rewritten in the same transaction, so a re-run never
duplicates records and a killed run leaves the old records intact.

A model-backed processor's calls are written as `ModelCall` nodes (roles "consolidation" and
"enrichment", appended: they are what the runs cost, failed calls included). When every model
step of a participant fails, nothing but those calls is written and `ConsolidationError` says so.
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import dataclass, field

import numpy as np
import polars as pl

from memora_graph import schema
from memora_graph.bank import Bank
from memora_graph.consolidate.memory import ParticipantMemory, load_memory
from memora_graph.consolidate.processors import Processors, StepReport, get_processors, register_processor
from memora_graph.consolidate.records import Consolidation, Enrichment
from memora_graph.consolidate.rules import RuleConsolidator, RuleEnricher, stable_id
from memora_graph.consolidate.task_records import Task, TaskPattern
from memora_graph.consolidate.task_rows import TaskRows, copy_task_rows
from memora_graph.errors import ConsolidationError
from memora_graph.llm.backends import CallRecord
from memora_graph.embed import encode_passages
from memora_graph.form.build import model_call_frame
from memora_graph.store import Store
from memora_graph.text import counted



@dataclass
class InferredKnowledge:
    participant: str
    consolidation: Consolidation
    enrichment: Enrichment
    routines: list[dict] = field(default_factory=list)  # Routine rows (without emb)
    preferences: list[dict] = field(default_factory=list)
    supported_by: list[tuple[str, str]] = field(default_factory=list)  # (routine or preference id, segment id)
    uses: list[tuple[str, str]] = field(default_factory=list)
    about: list[tuple[str, str]] = field(default_factory=list)
    dropped_ids: int = 0  # cited ids that do not exist in the bank (an LLM processor can invent some)
    dropped_records: int = 0  # records left without any existing evidence, so not written
    calls: list[CallRecord] = field(default_factory=list)  # model calls of this participant's run
    steps: list[StepReport] = field(default_factory=list)  # model steps and whether they produced records
    seconds: dict = field(default_factory=dict)
    tasks: list[Task] = field(default_factory=list)  # task-level memory (consolidate.tasks)
    task_rows: TaskRows | list[dict] = field(default_factory=list)  # the tasks as Task rows (evidence that exists)
    patterns: list[TaskPattern] = field(default_factory=list)  # how tasks are done (consolidate.patterns)

    @property
    def failed_steps(self) -> list[StepReport]:
        return [s for s in self.steps if not s.ok]

    def counts(self) -> dict:
        by_sub: dict[str, int] = {}
        for p in self.preferences:
            by_sub[p["subtype"]] = by_sub.get(p["subtype"], 0) + 1
        by_src: dict[str, int] = {}
        for r in self.routines:
            by_src[r["source"]] = by_src.get(r["source"], 0) + 1
        out = {"routines": len(self.routines), "preferences": len(self.preferences),
               "routines_by_source": by_src, "preferences_by_subtype": by_sub, "dropped_ids": self.dropped_ids,
               "dropped_records": self.dropped_records}
        if self.task_rows or self.patterns:
            fam: dict[str, int] = {}
            for x in self.patterns:
                fam[x.family] = fam.get(x.family, 0) + 1
            out.update(tasks=len(self.task_rows), task_patterns=fam)
        if self.calls or self.steps:
            out.update(model_calls=len(self.calls), failed_calls=sum(not c.ok for c in self.calls),
                       failed_steps=[f"{s.step}: {s.error}" for s in self.failed_steps])
        return out


def _words(*parts) -> str:
    return " ".join(str(p) for p in parts if p)


class _Collector:
    """Turns processor records into rows, keeping only evidence that exists in the bank."""

    def __init__(self, participant: str, segment_ids, entity_ids: set[str], processor: str):
        self.p = participant
        self.segments = segment_ids
        self.entities = entity_ids
        self.processor = processor
        self.out = InferredKnowledge(participant, Consolidation(participant=participant),
                                     Enrichment(participant=participant))
        self._ids: set[str] = set()

    def _valid(self, ids, known: set[str]) -> list[str]:
        ids = list(dict.fromkeys(ids))
        ok = [i for i in ids if i in known]
        self.out.dropped_ids += len(ids) - len(ok)
        return ok

    def _unique(self, rid: str) -> str:
        base, n = rid, 1
        while rid in self._ids:
            n += 1
            rid = f"{base}.{n}"
        self._ids.add(rid)
        return rid

    def routine(self, kind: str, key, *, goal, activity_type, steps, key_objects, episodes, segments, entities,
                videos: dict, count, confidence, source, detail: dict) -> None:
        episodes = self._valid(episodes, self.segments)
        segments = self._valid(segments, self.segments)
        if not episodes or not segments:
            self.out.dropped_records += 1
            return
        rid = self._unique(stable_id(self.p, kind, *key))
        text = _words(f"{goal}.", f"Steps: {'; '.join(steps[:8])}." if steps else "",
                      f"Objects: {', '.join(key_objects)}." if key_objects else "")
        self.out.routines.append({
            "id": rid, "participant": self.p, "goal": goal, "activity_type": activity_type, "canonical_steps": list(steps),
            "key_objects": list(key_objects), "supporting_episodes": episodes, "source_videos": sorted(videos),
            "count": int(count), "confidence": float(confidence), "retrieval_text": text, "source": source,
            "processor": self.processor, "detail": json.dumps({"videos": videos, **detail}, sort_keys=True),
        })
        self.out.supported_by += [(rid, s) for s in segments]
        self.out.uses += [(rid, e) for e in self._valid(entities, self.entities)]

    def preference(self, kind: str, key, *, subtype, statement, keywords, objects, context, episodes, entities,
                   videos: dict, count, confidence, source, evidence_summary, detail: dict) -> None:
        episodes = self._valid(episodes, self.segments)
        if not episodes:
            self.out.dropped_records += 1
            return
        rid = self._unique(stable_id(self.p, kind, *key))
        text = _words(f"{statement}.", f"Keywords: {', '.join(keywords)}." if keywords else "")
        self.out.preferences.append({
            "id": rid, "participant": self.p, "subtype": subtype, "statement": statement, "keywords": list(keywords),
            "objects": list(objects), "context": context, "supporting_episodes": episodes, "source_videos": sorted(videos),
            "count": int(count), "confidence": float(confidence), "retrieval_text": text, "source": source,
            "processor": self.processor, "evidence_summary": evidence_summary,
            "detail": json.dumps({"videos": videos, **detail}, sort_keys=True),
        })
        self.out.supported_by += [(rid, s) for s in episodes]
        self.out.about += [(rid, e) for e in self._valid(entities, self.entities)]


def _calls_since(processors: Processors, mark: int, participant: str) -> list[CallRecord]:
    if processors.call_log is None:
        return []
    return [r for r in processors.call_log.records[mark:] if r.tags.get("participant", participant) == participant]


def _marks(processors: Processors) -> tuple[int, int]:
    return (len(processors.call_log.records) if processors.call_log is not None else 0,
            len(processors.reports) if processors.reports is not None else 0)


def _per_video(memory: ParticipantMemory, processors: Processors, call_mark: int, report_mark: int) -> list:
    """Each video's consolidation; with `processors.concurrency` > 1 their model calls are in
    flight together, and the calls and step reports they added are put back in video order (so
    the ModelCall rows and the report do not depend on which reply came first)."""
    videos = list(memory.videos)
    if processors.concurrency <= 1 or len(videos) <= 1:
        return [processors.consolidation.consolidate_video(memory, v) for v in videos]
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=min(processors.concurrency, len(videos)),
                            thread_name_prefix="consolidate") as pool:
        per_video = list(pool.map(lambda v: processors.consolidation.consolidate_video(memory, v), videos))
    order = {v: i for i, v in enumerate(videos)}
    if processors.call_log is not None:
        log = processors.call_log
        log.records[call_mark:] = sorted(log.records[call_mark:], key=lambda r: order.get(r.tags.get("video"), len(order)))
    if processors.reports is not None:
        reps = processors.reports
        reps[report_mark:] = sorted(reps[report_mark:], key=lambda r: order.get(r.step.removeprefix("video "), len(order)))
    return per_video


def infer(memory: ParticipantMemory, entity_ids: set[str], processors: Processors) -> InferredKnowledge:
    """Run both processors over a loaded slice and collect validated rows (no I/O)."""
    call_mark, report_mark = _marks(processors)
    t0 = time.perf_counter()
    streaming = getattr(processors.consolidation, "consolidate_streaming", None)
    if streaming is not None and processors.concurrency <= 1:  # merged video by video: memory flat in the hours
        consolidation = streaming(memory)
    else:
        per_video = _per_video(memory, processors, call_mark, report_mark)
        consolidation = processors.consolidation.consolidate_participant(memory, per_video)
    t1 = time.perf_counter()
    enrichment = processors.enrichment.enrich(memory, consolidation)
    tasks, patterns = task_memory(memory)
    t2 = time.perf_counter()
    out = collect(memory.participant, memory.segment_ids, entity_ids, consolidation, enrichment, processors.name,
                  tasks=tasks, patterns=patterns)
    out.calls = _calls_since(processors, call_mark, memory.participant)
    out.steps = [r for r in (processors.reports or [])[report_mark:] if r.participant == memory.participant]
    out.seconds = {"consolidation": round(t1 - t0, 3), "enrichment": round(t2 - t1, 3),
                   "collect": round(time.perf_counter() - t2, 3)}
    return out


def task_memory(memory: ParticipantMemory) -> tuple[list[Task], list[TaskPattern]]:
    """Tasks and the patterns of how they are done: computed from the typed steps for every
    processor (a model-backed one writes the same task records as the rules)."""
    from memora_graph.consolidate.patterns import detect_all
    from memora_graph.consolidate.tasks import segment_tasks

    tasks = segment_tasks(memory)
    return tasks, detect_all(tasks)


def _collect_tasks(c: "_Collector", patterns: list[TaskPattern]) -> None:
    """A recurring task's canonical stages as a Routine row (source "task_routine"); every other
    pattern as a Preference row (source "tasks") whose subtype is its family."""
    for p in patterns:
        common = {"count": p.count, "total": p.total, "exceptions": p.exceptions, "tasks": p.tasks[:30], **p.detail}
        if p.family == "canonical":
            stages = p.detail.get("stages", {})
            steps = [f"{st}: {x}" for st in ("setup", "main", "finish", "cleanup") for x in stages.get(st, [])]
            c.routine("task_routine", p.key, goal=f"{p.goal} (how it is usually done)", activity_type="task_routine",
                      steps=steps, key_objects=p.objects[:8], episodes=p.evidence[:10], segments=p.evidence,
                      entities=[], videos=p.videos, count=p.count, confidence=p.confidence, source="task_routine",
                      detail={**common, "statement": p.statement, "steps": [a.model_dump() for a in p.actions]})
            continue
        words = [w for a in p.actions for w in (a.verb.replace("-", " "), a.noun.replace(":", " "), a.place) if w]
        c.preference("pref", (p.family, *p.key), subtype=p.family, statement=p.statement,
                     keywords=list(dict.fromkeys([p.family, *words])), objects=p.objects,
                     context=p.detail.get("way") or p.goal or p.family,
                     episodes=p.evidence, entities=[], videos=p.videos, count=p.count, confidence=p.confidence,
                     source="tasks", evidence_summary=f"{p.count} of {p.total} in {len(p.tasks)} tasks",
                     detail={**common, "actions": [a.model_dump() for a in p.actions]})


def collect(participant: str, segment_ids, entity_ids: set[str], consolidation: Consolidation, enrichment: Enrichment,
            processor: str, tasks: list[Task] | None = None, patterns: list[TaskPattern] | None = None) -> InferredKnowledge:
    """The records of both processors (and the task memory) as Routine / Preference rows, keeping
    only the evidence ids that exist (`segment_ids`, `entity_ids`: anything with `in`)."""
    c = _Collector(participant, segment_ids, entity_ids, processor)
    c.out.consolidation, c.out.enrichment = consolidation, enrichment
    c.out.tasks, c.out.patterns = list(tasks or []), list(patterns or [])
    c.out.task_rows = TaskRows(participant, c.out.tasks, segment_ids)  # made when written
    for s in consolidation.storage_preferences:
        c.preference("pref", ("storage", s.object, s.context), subtype="storage", statement=s.statement,
                     keywords=[s.object_name, s.preferred_location, s.context.replace("_", " "), "store", "keep", "put"],
                     objects=[s.object_name], context=s.context, episodes=s.supporting_episodes, entities=s.entities,
                     videos=s.videos, count=s.count, confidence=s.confidence, source="consolidation",
                     evidence_summary=f"{s.count} of {s.total} observations in {counted(len(s.videos), 'video')}",
                     detail={"object": s.object, "preferred_location": s.preferred_location, "place": s.place,
                             "total": s.total, "alternatives": s.alternatives})
    for h in consolidation.organizational_habits:
        c.preference("pref", ("habit", h.trigger, h.next_action), subtype="habit", statement=h.habit,
                     keywords=[*h.trigger.split(), *h.next_action.split()], objects=h.objects_involved,
                     context=h.trigger, episodes=h.supporting_episodes, entities=h.entities, videos=h.videos,
                     count=h.count, confidence=h.confidence, source="consolidation",
                     evidence_summary=f"{h.count} of {h.trigger_count} times in {counted(len(h.videos), 'video')}",
                     detail={"trigger": h.trigger, "next_action": h.next_action, "trigger_count": h.trigger_count,
                             **({"trigger_step": h.trigger_step.model_dump()} if h.trigger_step else {}),
                             **({"next_step": h.next_step.model_dump()} if h.next_step else {})})
    for w in consolidation.workflow_patterns:
        c.preference("pref", ("workflow", w.category, w.use, w.then), subtype="workflow", statement=w.pattern,
                     keywords=[w.category, *w.objects[:6], *w.use.replace("@", "").split(), *w.then.split()],
                     objects=w.objects, context=w.category, episodes=w.supporting_episodes, entities=w.entities,
                     videos=w.videos, count=w.count, confidence=w.confidence, source="consolidation",
                     evidence_summary=f"{w.count} times with {counted(len(w.objects), 'object')} in {counted(len(w.videos), 'video')}",
                     detail={"category": w.category, "use": w.use, "then": w.then})
    for a in consolidation.action_sequences:
        c.routine("seq", tuple(a.steps), goal=a.title, activity_type=a.activity_type, steps=a.steps,
                  key_objects=a.key_objects, episodes=a.supporting_episodes, segments=a.segments, entities=a.entities,
                  videos=a.videos, count=a.count, confidence=a.confidence, source="action_sequence",
                  detail={"steps": [x.model_dump() for x in a.actions]} if a.actions else {})
    for r in enrichment.routine_skills:
        c.routine("routine", (r.goal,), goal=r.goal, activity_type=r.activity_type, steps=r.canonical_steps,
                  key_objects=r.key_objects, episodes=r.supporting_episodes, segments=r.segments, entities=r.entities,
                  videos=r.videos, count=r.count, confidence=r.confidence, source="routine_skill",
                  detail={"episodes": [e.model_dump() for e in r.episodes],
                          **({"steps": [x.model_dump() for x in r.actions]} if r.actions else {})})
    for g in enrichment.generated_preferences:
        c.preference("pref", ("generated", g.subtype, g.preference), subtype=g.subtype, statement=g.preference,
                     keywords=g.keywords, objects=g.objects, context=g.context, episodes=g.supporting_evidence_ids,
                     entities=g.entities, videos=g.videos, count=g.count, confidence=g.confidence, source="enrichment",
                     evidence_summary=g.evidence_summary,
                     detail={"alternatives": g.alternatives,
                             **({"actions": [x.model_dump() for x in g.actions]} if g.actions else {})})
    _collect_tasks(c, c.out.patterns)
    return c.out


def _frame(table: str, rows: list[dict], vecs: np.ndarray, dim: int) -> pl.DataFrame:
    """Routine / Preference rows with their embeddings, columns and types from the schema."""
    emb = pl.Series("emb", np.asarray(vecs, dtype=np.float32).reshape(len(rows), dim), dtype=pl.Array(pl.Float32, dim))
    return schema.frame(table, rows).with_columns(emb)


def _embed(store: Store, participant: str, texts: list[str], embedder) -> np.ndarray:
    """Embeddings of the retrieval texts; a text already stored (a re-run) keeps its vector."""
    if not texts:
        return np.zeros((0, embedder.dim), dtype=np.float32)
    known = {r["text"]: r["emb"] for r in store.fetch("_inferred_embeddings", participant=participant)
             if r["emb"] is not None}
    todo = sorted({t for t in texts if t not in known})
    fresh = dict(zip(todo, encode_passages(embedder, todo))) if todo else {}
    return np.asarray([fresh[t] if t in fresh else known[t] for t in texts], dtype=np.float32)


def _call_frame(participant: str, records: list[CallRecord]) -> pl.DataFrame | None:
    """ModelCall rows of consolidation calls (turn -1, no segment). Ids carry a run id, so the
    calls of every run are kept."""
    return model_call_frame(participant, records, f"{participant}:inferred:{uuid.uuid4().hex[:10]}")


def write_calls(store: Store, participant: str, records: list[CallRecord]) -> None:
    """Record model calls on their own (a run that wrote no inferred knowledge still cost them)."""
    frame = _call_frame(participant, records)
    if frame is not None:
        with store.transaction():
            store.copy("ModelCall", frame)


def write_inferred(store: Store, knowledge: InferredKnowledge, embedder) -> None:
    """Replace the participant's Routine / Preference records in one transaction (with the
    model calls that made them, if any)."""
    p = knowledge.participant
    texts = [r["retrieval_text"] for r in knowledge.routines] + [r["retrieval_text"] for r in knowledge.preferences]
    vecs = _embed(store, p, texts, embedder)
    nr = len(knowledge.routines)
    routines = _frame("Routine", knowledge.routines, vecs[:nr], embedder.dim) if knowledge.routines else None
    prefs = _frame("Preference", knowledge.preferences, vecs[nr:], embedder.dim) if knowledge.preferences else None
    routine_ids = {r["id"] for r in knowledge.routines}
    sup = sorted(set(knowledge.supported_by))
    sup_r = pl.DataFrame({"from": [a for a, _ in sup if a in routine_ids], "to": [b for a, b in sup if a in routine_ids]})
    sup_p = pl.DataFrame({"from": [a for a, _ in sup if a not in routine_ids], "to": [b for a, b in sup if a not in routine_ids]})
    uses = pl.DataFrame({"from": [a for a, _ in sorted(set(knowledge.uses))], "to": [b for _, b in sorted(set(knowledge.uses))]},
                        schema={"from": pl.String, "to": pl.String})
    about = pl.DataFrame({"from": [a for a, _ in sorted(set(knowledge.about))], "to": [b for _, b in sorted(set(knowledge.about))]},
                         schema={"from": pl.String, "to": pl.String})
    with store.transaction():
        store.run("_inferred_clear", participant=p)
        _write_tasks(store, p, knowledge)
        if routines is not None:
            store.copy("Routine", routines)
        if prefs is not None:
            store.copy("Preference", prefs)
        store.copy("SUPPORTED_BY", sup_r, from_table="Routine", to_table="Segment")
        store.copy("SUPPORTED_BY", sup_p, from_table="Preference", to_table="Segment")
        store.copy("USES", uses)
        store.copy("ABOUT", about)
        calls = _call_frame(p, knowledge.calls)
        if calls is not None:
            store.copy("ModelCall", calls)


def _write_tasks(store: Store, participant: str, knowledge: InferredKnowledge) -> None:
    if "Task" not in store.tables():  # a bank opened without the task schema (read as it is)
        return
    store.run("_task_clear", participant=participant)
    if knowledge.task_rows:
        copy_task_rows(store, knowledge.task_rows)  # a chunk of tasks per COPY: one frame of them all was held several times


def consolidate_participant(store: Store, participant: str, embedder, processors: str | Processors = "deterministic") -> InferredKnowledge:
    """Consolidate + enrich one participant's memory in an open read-write store.

    A model server that fails raises (after its calls are recorded); a model step whose reply
    stayed invalid only loses that step's records, unless every step failed: then the previous
    inferred knowledge stays and ConsolidationError is raised."""
    procs = get_processors(processors) if isinstance(processors, str) else processors
    t0 = time.perf_counter()
    memory = load_memory(store, participant)
    entity_ids = {r["id"] for r in store.fetch("_consolidate_entity_ids", participant=participant)}
    t1 = time.perf_counter()
    call_mark, _ = _marks(procs)
    try:
        knowledge = infer(memory, entity_ids, procs)
    except BaseException:
        try:  # best effort: the calls a failed run made are still worth recording
            write_calls(store, participant, _calls_since(procs, call_mark, participant))
        except Exception:  # noqa: BLE001 - the original error is the one to report
            pass
        raise
    t2 = time.perf_counter()
    if knowledge.steps and not any(s.ok for s in knowledge.steps):
        write_calls(store, participant, knowledge.calls)
        first = knowledge.steps[0]
        raise ConsolidationError(
            f"{participant}: every model step failed ({len(knowledge.steps)}; first: {first.step}: {first.error}). "
            f"Its inferred knowledge was left as it was; the failed calls are in `memora stats BANK --calls failed`.")
    write_inferred(store, knowledge, embedder)
    knowledge.seconds.update({"load": round(t1 - t0, 3), "write": round(time.perf_counter() - t2, 3)})
    knowledge.seconds["total"] = round(time.perf_counter() - t0, 3)
    return knowledge


def clear_inferred(store: Store, participant: str) -> None:
    with store.transaction():
        store.run("_inferred_clear", participant=participant)
        if "Task" in store.tables():
            store.run("_task_clear", participant=participant)


def finish_participant(bank: Bank, participant: str, embedder, episodic: bool = False,
                       processors: str | Processors = "deterministic", fts: bool = False,
                       timings: dict | None = None) -> InferredKnowledge | None:
    """The step after a participant's build (or `memora consolidate`): consolidation + enrichment
    (or, for a MEMORA-Episodic bank, no inferred knowledge at all), then, only if `fts`, the
    full-text indexes (read by the 'fts' / 'kuzu' / 'hnsw' retrieval recipes only; the default
    recipe needs none; an index the database has is kept and new rows join it). Records it all,
    with the indexes the database has, in the manifest.

    `timings`, if given, receives the seconds of each step: open (and schema check),
    consolidation (without its embedding), embedding, indexes, checkpoint (closing the
    database), manifest."""
    name = processors if isinstance(processors, str) else processors.name
    emb0 = getattr(embedder, "seconds", 0.0)
    t0 = time.perf_counter()
    building = bank.writing_here(participant)  # the last step of this process's build: it records the integrity
    # checked first (unless this process is building it); records its integrity again on close
    store = bank.open(participant, read_only=False)
    spent: dict[str, float] = {}
    try:
        store.apply_schema()
        t1 = time.perf_counter()
        if episodic:
            clear_inferred(store, participant)
            knowledge = None
        else:
            knowledge = consolidate_participant(store, participant, embedder, processors)
        counts = store.fetch("_inferred_counts", participant=participant)[0]
        t2 = time.perf_counter()
        if fts:
            store.ensure_indexes(fts=True)
        indexes = sorted(store.indexes())
        t3 = time.perf_counter()
        spent["embedding"] = getattr(embedder, "seconds", 0.0) - emb0
        spent.update(open=t1 - t0, consolidation=t2 - t1 - spent["embedding"], indexes=t3 - t2)
    finally:
        t3 = time.perf_counter()
        store.close()
    t4 = time.perf_counter()
    with bank.manifest_lock():  # other participants may be finishing in parallel processes
        data = bank.manifest()
        entry = data["participants"].get(participant)
        if entry is not None:
            entry.setdefault("counts", {}).update({"routines": int(counts["routines"]),
                                                   "preferences": int(counts["preferences"])})
            entry["consolidated"] = not episodic
            entry["inferred"] = None if episodic else {"processor": name, **knowledge.counts()}
        bank.set_indexes(data, participant, indexes)
        flags = [e.get("consolidated", False) for e in data["participants"].values()]
        data["consolidated"] = bool(flags) and all(flags)
        data["condition"] = "memora_full" if data["consolidated"] else (
            "memora_episodic" if not any(flags) else "mixed")
        bank.write_manifest(data)
    if building:
        bank.record_integrity(participant)  # the build is complete
    if timings is not None:
        timings.update(spent, checkpoint=t4 - t3, manifest=time.perf_counter() - t4)
    return knowledge


# -- the built-in processors ---------------------------------------------------------------------------


def deterministic_processors() -> Processors:
    """The rule-based processors (CPU, no model): the default."""
    return Processors("deterministic", RuleConsolidator(), RuleEnricher())


def llm_processors(**options) -> Processors:
    """The model-backed processors (memora_graph/consolidate/llm), imported only when asked for."""
    from memora_graph.consolidate.llm import make_llm_processors

    return make_llm_processors(**options)


register_processor("deterministic", deterministic_processors)
register_processor("llm", llm_processors)
