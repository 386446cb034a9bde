"""Edit(M, z) by a model: the online memory processor as an `EditPolicy`.

One call per segment: the model sees a compact registry (at most `prompt_budget` entities,
chosen by dense similarity to the new observations, numbered 1..n so it never has to copy
long ids) and the segment's objects, and answers {"object_operations": [...]}. The answer is
validated (ADD needs data, UPDATE needs changes; one repair turn in the backend) and mapped
back onto EditOps with these repairs: ADD on an existing object
becomes UPDATE, UPDATE on an unknown number becomes ADD, DELETE on an unknown number is
dropped (DELETE_INVALID), and an observation the model left out still lands in the history
(FALLBACK_NOOP / FALLBACK_UPDATE / ADD), so the editor's state history stays complete.
"""

from __future__ import annotations

import json
from collections import Counter
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from memora_graph.form.editor import (
    ATTRS, DEFAULT_PROMPT_BUDGET, EntityState, add_fields, compatible, identity_text, update_or_noop,
)
from memora_graph.llm.backends import Backend
from memora_graph.perceive.vlm import normalize_location
from memora_graph.records import EditOp, LayeredSegment, ObjectObservation

PROMPT_VERSION = "editor-v1"
CHANGE_FIELDS = ("state", "location", "held_by", *ATTRS)


class ObjectOperation(BaseModel):
    model_config = ConfigDict(extra="ignore")

    event: Literal["ADD", "UPDATE", "DELETE", "NOOP"]
    observation: int | None = Field(None, description="number of the new observation this operation is about")
    object_id: int | str | None = Field(None, description="registry number (UPDATE, NOOP, DELETE) or the new object's id (ADD)")
    data: dict[str, Any] | None = None
    changes: dict[str, Any] | None = None
    merged_into: int | None = Field(None, description="DELETE of a duplicate: the registry number it is the same object as")
    reason: str = ""

    @field_validator("event", mode="before")
    @classmethod
    def _upper(cls, v):
        return v.upper() if isinstance(v, str) else v

    @model_validator(mode="after")
    def _payload(self):
        if self.event == "ADD" and not self.data:
            raise ValueError("an ADD needs `data` (name, state, location, ...)")
        if self.event == "UPDATE" and not self.changes:
            raise ValueError("an UPDATE needs `changes` (only the fields that changed)")
        return self


class EditorReply(BaseModel):
    object_operations: list[ObjectOperation]


SYSTEM_PROMPT = f"""You are the online memory processor of a personal kitchen memory (prompt {PROMPT_VERSION}).
You edit Entity Memory: a registry of the objects this person has, each with its current state and place.
For every new observation choose one operation:
- ADD: an object that is not in the registry (object_id = its new id, data = name, state, location, held_by, color, material, size).
- UPDATE: a registry object whose state, location, holder or attributes changed (object_id = its registry number,
  changes = only the fields that changed).
- NOOP: a registry object seen again, unchanged (object_id = its registry number).
- DELETE: a registry object this observation shows is gone for good (eaten, thrown away), or a registry record
  that duplicates another one (give merged_into = the number of the record to keep).
Keep the exact registry number of an existing object; only ADD creates an object. A movement trajectory
ends at the location to record. Give a short reason for each operation.
Answer with one JSON object:
{{"object_operations": [{{"event": "ADD" | "UPDATE" | "NOOP" | "DELETE", "observation": number,
  "object_id": registry number or new id, "data": {{...}} (ADD), "changes": {{...}} (UPDATE),
  "merged_into": registry number (DELETE of a duplicate), "reason": str}}]}}
with one operation per observation (plus a DELETE for each duplicate record)."""


def _fuzzy(obs: ObjectObservation, e: EntityState) -> int:
    """How surely `e` is the observed object by name: 3 exact id, 2 one id contains the other,
    1 same last noun with at least half the words shared, 0 not at all."""
    if e.object_id == obs.object_id:
        return 3
    a, b = obs.object_id.split("_"), e.object_id.split("_")
    if any(w.isdigit() for w in a + b):
        return 0  # numbered look-alikes are distinct on purpose
    if set(a) <= set(b) or set(b) <= set(a):
        return 2
    if a[-1] == b[-1] and len(set(a) & set(b)) / len(set(a) | set(b)) >= 0.5:
        return 1
    return 0


class LLMEditorPolicy:
    """The model-backed editor: the same `decide` contract as `DeterministicPolicy`."""

    name = "llm"
    role = "editor"

    def __init__(self, backend: Backend, prompt_budget: int = DEFAULT_PROMPT_BUDGET):
        backend.require(self.role)
        self.backend = backend
        self.prompt_budget = prompt_budget
        self.repairs: Counter[str] = Counter()  # repair kind -> count, for reports and tests

    # -- prompt --------------------------------------------------------------------------------
    def registry(self, observations: list[ObjectObservation], candidates: list[list[EntityState]], embed) -> list[EntityState]:
        """At most `prompt_budget` live entities: name matches first, then by similarity, then recency."""
        pool: dict[str, EntityState] = {}
        for cands in candidates:
            for e in cands:
                if e.status == "active":
                    pool.setdefault(e.id, e)
        entities = list(pool.values())
        if len(entities) <= self.prompt_budget:
            return sorted(entities, key=lambda e: e.id)
        match = {e.id: max((_fuzzy(o, e) for o in observations), default=0) for e in entities}
        sim = dict.fromkeys(match, 0.0)
        if embed is not None:
            q = np.stack([embed(identity_text(o.name, o.category)) for o in observations])
            for e in entities:
                if e.emb is not None:
                    sim[e.id] = float(np.max(q @ e.emb))
        ranked = sorted(entities, key=lambda e: (-match[e.id], -round(sim[e.id], 4), -e.last_seen, e.id))
        return sorted(ranked[: self.prompt_budget], key=lambda e: e.id)

    @staticmethod
    def _groups(observations: list[ObjectObservation]) -> list[list[int]]:
        """Observation indexes per object id, in first-seen order (a trajectory is one group)."""
        groups: dict[str, list[int]] = {}
        for i, o in enumerate(observations):
            groups.setdefault(o.object_id, []).append(i)
        return list(groups.values())

    def messages(self, segment: LayeredSegment, observations: list[ObjectObservation], registry: list[EntityState],
                 groups: list[list[int]]) -> list[dict[str, Any]]:
        reg = "\n".join(f"[{n}] {e.compact()}" for n, e in enumerate(registry, start=1)) or "(empty)"
        obs_lines = []
        for g, idx in enumerate(groups):
            last = observations[idx[-1]]
            entry = {"object_id": last.object_id, "name": last.name, "state": last.state, "location": last.location,
                     "held_by": last.held_by, **last.attributes()}
            if last.is_fixture:
                entry["fixture"] = True
            if len(idx) > 1:
                entry["trajectory"] = " -> ".join(observations[i].location for i in idx)
            if last.action:
                entry["action"] = last.action
            obs_lines.append(f"({g}) {json.dumps(entry, ensure_ascii=False)}")
        text = (f"Turn {segment.turn_id} of video {segment.video_id} ({segment.t_start:g}-{segment.t_end:g} s). "
                f"Activity: {segment.activity.summary}\n"
                f"Current registry ({len(registry)} objects):\n{reg}\n"
                f"New observations ({len(groups)}):\n" + "\n".join(obs_lines))
        return [{"role": "system", "content": SYSTEM_PROMPT}, {"role": "user", "content": text}]

    # -- decide --------------------------------------------------------------------------------
    def decide(self, segment, observations, candidates, embed) -> list[list[EditOp]]:
        if not observations:
            return []
        registry = self.registry(observations, candidates, embed)
        groups = self._groups(observations)
        tags = {"participant": segment.participant_id, "video": segment.video_id, "turn": segment.turn_id,
                "segment": segment.segment_id, "prompt": PROMPT_VERSION}
        reply = self.backend.chat(self.messages(segment, observations, registry, groups), role=self.role,
                                  response_model=EditorReply, tags=tags)
        return self.map_operations(reply.parsed.object_operations, observations, registry, groups)

    def map_operations(self, operations: list[ObjectOperation], observations: list[ObjectObservation],
                       registry: list[EntityState], groups: list[list[int]]) -> list[list[EditOp]]:
        """The model's operations -> EditOps per observation, with the repairs applied."""
        by_group: dict[int, list[ObjectOperation]] = {}
        first_of = {observations[idx[0]].object_id: g for g, idx in enumerate(groups)}
        for op in operations:
            g = op.observation
            if (g is None or not 0 <= g < len(groups)) and isinstance(op.object_id, str):
                g = first_of.get(op.object_id)  # the paper's format keys operations by object id only
            if g is None or not 0 <= g < len(groups):
                self.repairs["no_observation"] += 1
                continue
            by_group.setdefault(g, []).append(op)

        out: list[list[EditOp]] = [[] for _ in observations]
        for g, idx in enumerate(groups):
            first, last = observations[idx[0]], observations[idx[-1]]
            merges, main = [], None
            for op in by_group.get(g, []):
                mapped = self._map_one(op, last, registry)
                if mapped is None:
                    continue
                if mapped.op == "DELETE" and mapped.merged_into:
                    merges.append(mapped)
                elif main is None:
                    main = mapped
                else:
                    self.repairs["extra_operation"] += 1
            if main is None:
                main = self._fallback(last, registry)
            keeper = main.entity_id if main.op != "ADD" else None
            merges = [m for m in merges if m.entity_id != keeper]
            out[idx[0]].extend(merges)
            if len(idx) == 1:
                out[idx[0]].append(main)
                continue
            # A trajectory: the decision is about where the object ends up; the earlier stops of
            # the same object are follow-on sightings of that decision's entity.
            if main.op == "ADD":
                for i in idx:  # later ADDs of the same object fold into the new record (editor repair)
                    out[i].append(main if i == idx[0] else EditOp(
                        op="ADD", entity_id="", reason="same object later in this turn", changes=add_fields(observations[i])))
                continue
            prev = _snapshot(registry, main.entity_id)
            for i in idx[:-1]:
                out[i].append(_follow_on(main.entity_id, prev, observations[i]))
                prev = _fields(observations[i])
            out[idx[-1]].append(main)
        return out

    def _map_one(self, op: ObjectOperation, obs: ObjectObservation, registry: list[EntityState]) -> EditOp | None:
        reason = op.reason.strip() or f"model: {op.event}"
        if op.event == "ADD":
            target = self._resolve(op.object_id, registry) if isinstance(op.object_id, int) else None
            if target is None:
                scored = [(_fuzzy(obs, e), e.last_seen, e) for e in registry if compatible(e, obs.attributes())]
                best = max(scored, key=lambda s: (s[0], s[1]), default=(0, 0, None))
                target = best[2] if best[0] >= 2 else None
            if target is not None:
                self.repairs["add_on_existing"] += 1
                fixed = update_or_noop(target, obs)
                return fixed.model_copy(update={"reason": f"{reason} [repair: ADD on existing id {target.object_id}]"})
            return EditOp(op="ADD", entity_id="", reason=reason, changes=add_fields(obs))
        target = self._resolve(op.object_id, registry)
        if target is None:
            if op.event == "DELETE":
                self.repairs["delete_invalid"] += 1
                return None
            self.repairs["unknown_to_add"] += 1
            return EditOp(op="ADD", entity_id="", reason=f"{reason} [repair: {op.event} on unknown id {op.object_id}]",
                          changes=add_fields(obs))
        if op.event == "DELETE":
            if op.merged_into is not None:
                keeper = self._resolve(op.merged_into, registry)
                if keeper is None or keeper.id == target.id:
                    self.repairs["delete_invalid"] += 1
                    return None
                return EditOp(op="DELETE", entity_id=target.id, merged_into=keeper.id, reason=reason)
            return EditOp(op="DELETE", entity_id=target.id, reason=reason, changes={"state": obs.state})
        if op.event == "UPDATE":
            changes = _clean_changes(op.changes or {})
            if not changes:
                self.repairs["empty_changes"] += 1
                fixed = update_or_noop(target, obs)
                return fixed.model_copy(update={"reason": f"{reason} [repair: no usable changes]"})
            return EditOp(op="UPDATE", entity_id=target.id, reason=reason, changes=changes)
        if obs.location != target.location:  # a NOOP that would leave the record at the old place
            self.repairs["noop_moved"] += 1
            fixed = update_or_noop(target, obs)
            return fixed.model_copy(update={"reason": f"{reason} [repair: NOOP but the location changed]"})
        return EditOp(op="NOOP", entity_id=target.id, reason=reason)

    def _fallback(self, obs: ObjectObservation, registry: list[EntityState]) -> EditOp:
        """The model said nothing about this observation: it still lands in the history."""
        self.repairs["omitted"] += 1
        same = [e for e in registry if e.object_id == obs.object_id]
        if same:
            fixed = update_or_noop(max(same, key=lambda e: e.last_seen), obs)
            tag = "FALLBACK_NOOP" if fixed.op == "NOOP" else "FALLBACK_UPDATE"
            return fixed.model_copy(update={"reason": f"{fixed.reason} [{tag}: omitted by the editor model]"})
        return EditOp(op="ADD", entity_id="", reason=f"new object '{obs.name}' [FALLBACK_ADD: omitted by the editor model]",
                      changes=add_fields(obs))

    @staticmethod
    def _resolve(ref: int | str | None, registry: list[EntityState]) -> EntityState | None:
        if isinstance(ref, bool) or ref is None:
            return None
        if isinstance(ref, str) and ref.strip().lstrip("[").rstrip("]").isdigit():
            ref = int(ref.strip().lstrip("[").rstrip("]"))
        if isinstance(ref, int):
            return registry[ref - 1] if 1 <= ref <= len(registry) else None
        hits = [e for e in registry if ref in (e.object_id, e.id)]
        return hits[0] if len(hits) == 1 else None


def _clean_changes(changes: dict[str, Any]) -> dict[str, str]:
    out = {}
    for k, v in changes.items():
        k = k.strip().lower().replace("current_state", "state")
        if k not in CHANGE_FIELDS:
            continue
        v = "" if v is None else str(v).strip()
        out[k] = normalize_location(v) if k == "location" else (v.lower() if k in ATTRS else v)
    return out


def _fields(o: ObjectObservation) -> dict[str, str]:
    """What an earlier stop of a trajectory may change: where the object is and who holds it
    (its state is the model's decision at the last stop)."""
    return {"location": o.location, "held_by": o.held_by or ""}


def _snapshot(registry: list[EntityState], entity_id: str) -> dict[str, str]:
    e = next((e for e in registry if e.id == entity_id), None)
    return {"location": e.location, "held_by": e.held_by} if e else {}


def _follow_on(entity_id: str, prev: dict[str, str], obs: ObjectObservation) -> EditOp:
    now = _fields(obs)
    changes = {k: v for k, v in now.items() if prev.get(k) != v}
    if not changes:
        return EditOp(op="NOOP", entity_id=entity_id, reason=f"trajectory stop at {obs.location}, unchanged")
    return EditOp(op="UPDATE", entity_id=entity_id, reason=f"trajectory stop: {obs.narration}", changes=changes)
