"""Edit(M, z) for Entity Memory: one ADD / UPDATE / DELETE / NOOP decision per object observation.

The registry is the participant's current entities. A policy decides; the editor applies the
decision, appends an immutable StateEvent for every observation (so the history keeps every
state, even unchanged ones, as in the paper's plate example) and logs an EditOp with its reason.
Policies are pluggable: `DeterministicPolicy` (default, rules plus embedding tie-breaks),
`RawPolicy` (no editing: one record per observation), and model-backed editors later.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from memora_graph.form.repair import PerceptionRepairs, wants_repairs
from memora_graph.perceive.vocab import KEPT_STATE, NEW_STATE, RETRACTING_VERBS
from memora_graph.records import EditOp, LayeredSegment, ObjectObservation

ATTRS = ("color", "material", "size")
DEFAULT_PROMPT_BUDGET = 50


@dataclass
class EntityState:
    """An Entity row as the editor holds it in memory."""

    id: str
    participant: str
    object_id: str
    kind: str
    name: str
    category: str = ""
    color: str = ""
    material: str = ""
    size: str = ""
    is_fixture: bool = False
    status: str = "active"
    merged_into: str = ""
    state: str = ""
    location: str = ""
    held_by: str = ""
    first_seen: float = 0.0
    first_video: str = ""
    first_turn: int = 0
    last_seen: float = 0.0
    last_video: str = ""
    last_turn: int = 0
    n_observations: int = 0
    emb: np.ndarray | None = field(default=None, repr=False)

    def attrs(self) -> dict[str, str]:
        d = self.__dict__
        return {a: d[a] for a in ATTRS if d[a]}

    def identity_text(self) -> str:
        return identity_text(self.name, self.category)

    def compact(self) -> str:
        """One line of the compact registry a model editor sees."""
        attrs = ", ".join(f"{k}={v}" for k, v in self.attrs().items())
        return f"{self.object_id}: {self.name} ({attrs}) state={self.state} at {self.location}"


def identity_text(name: str, category: str) -> str:
    return f"{name} ({category})" if category else name


def compatible(entity: EntityState, attrs: dict[str, str]) -> bool:
    """Attributes never contradict: each is unknown on one side or equal."""
    return all(not getattr(entity, k) or getattr(entity, k) == v for k, v in attrs.items())


class EditPolicy(Protocol):
    name: str
    # True where `decide` reads only the live entities of each observation's own kind (by name):
    # the editor then hands it exactly those, and skips the embedding top-k over the whole registry
    # that a model's prompt needs (a matrix-vector product over every live entity per observation,
    # which made a long build's cost per hour grow with its entity count). Absent: False.
    same_kind_only: bool

    def decide(
        self, segment: LayeredSegment, observations: list[ObjectObservation],
        candidates: list[list[EntityState]], embed,
    ) -> list[list[EditOp]]:
        """For each observation, the ops to apply (normally one; a merge adds DELETEs first)."""


class DeterministicPolicy:
    """Identity by normalized name and attributes; embedding similarity breaks ties."""

    name = "deterministic"
    same_kind_only = True  # `_decide_one` keeps only candidates of the observation's kind
    perception_repairs = True  # the editor runs form/repair.py's rules with it

    def decide(self, segment, observations, candidates, embed) -> list[list[EditOp]]:
        return [self._decide_one(obs, cands, embed) for obs, cands in zip(observations, candidates)]

    def _decide_one(self, obs: ObjectObservation, cands: list[EntityState], embed) -> list[EditOp]:
        attrs = obs.attributes()
        same = [e for e in cands if e.kind == obs.kind and e.status == "active"]
        fits = [e for e in same if compatible(e, attrs)]
        if not fits:
            why = (f"new object '{obs.name}'" if not same else
                   f"'{obs.name}' conflicts in attributes with {', '.join(e.object_id for e in same)}")
            return [EditOp(op="ADD", entity_id="", reason=why, changes=add_fields(obs))]
        ops: list[EditOp] = []
        keeper = self._pick(obs, fits, embed)
        # Two live records that the observation cannot tell apart are one object: retract the
        # weaker identification and fold it into the keeper.
        dupes = [e for e in fits if e is not keeper and compatible(keeper, e.attrs()) and compatible(e, keeper.attrs())]
        for d in dupes:
            ops.append(EditOp(op="DELETE", entity_id=d.id, merged_into=keeper.id,
                              reason=f"'{d.name}' and '{keeper.name}' are one object (same name, compatible attributes)"))
        if obs.action in RETRACTING_VERBS and not obs.is_fixture and obs.state in ("discarded", "eaten", "drunk"):
            ops.append(EditOp(op="DELETE", entity_id=keeper.id, reason=f"retracted: '{obs.narration}' removes it from the scene",
                              changes={"state": obs.state}))
            return ops
        ops.append(update_or_noop(keeper, obs))
        return ops

    @staticmethod
    def _pick(obs: ObjectObservation, fits: list[EntityState], embed) -> EntityState:
        if len(fits) == 1:
            return fits[0]
        attrs = obs.attributes()
        exact = [e for e in fits if e.attrs() == attrs]
        if len(exact) == 1:
            return exact[0]
        q = embed(identity_text(obs.name, obs.category)) if embed else None

        def score(e: EntityState):
            sim = float(q @ e.emb) if q is not None and e.emb is not None else 0.0
            return (round(sim, 4), e.location == obs.location, e.last_seen, e.id)

        return max(fits, key=score)


class RawPolicy:
    """No editing: every observation becomes its own record (the compression baseline)."""

    name = "raw"
    same_kind_only = True  # reads no candidate at all

    def decide(self, segment, observations, candidates, embed) -> list[list[EditOp]]:
        return [[EditOp(op="ADD", entity_id="", reason="raw mode: one record per observation", changes=add_fields(o))]
                for o in observations]


# The editor policies an annotation build runs by name (`memora build --mode NAME`; the bank's
# manifest records the name as its mode). The model-backed policy of video builds
# (form/llm_editor.py) is made from a backend instead.
_POLICIES: dict[str, Callable[[], EditPolicy]] = {}


def register_editor_policy(mode: str, factory: Callable[[], EditPolicy]) -> None:
    if mode in _POLICIES:
        raise ValueError(f"editor policy {mode!r} is already registered")
    _POLICIES[mode] = factory


def editor_policy_names() -> list[str]:
    return list(_POLICIES)


def get_editor_policy(mode: str) -> EditPolicy:
    if mode not in _POLICIES:
        raise ValueError(f"no editor policy {mode!r}; registered: {', '.join(_POLICIES)}")
    return _POLICIES[mode]()


register_editor_policy("edited", DeterministicPolicy)
register_editor_policy("raw", RawPolicy)


def update_or_noop(entity: EntityState, obs: ObjectObservation) -> EditOp:
    """UPDATE with the fields that changed, or NOOP when the observation repeats the record."""
    changes = {}
    if obs.state != KEPT_STATE and obs.state != entity.state:  # KEPT_STATE: the observation says nothing of it
        changes["state"] = obs.state
    if obs.location != entity.location:
        changes["location"] = obs.location
    if (obs.held_by or "") != entity.held_by:
        changes["held_by"] = obs.held_by or ""
    for k, v in obs.attributes().items():
        if not getattr(entity, k):
            changes[k] = v
    if changes:
        what = ", ".join(f"{k} {getattr(entity, k) or '-'} -> {v or '-'}" for k, v in changes.items())
        return EditOp(op="UPDATE", entity_id=entity.id, reason=what, changes=changes)
    return EditOp(op="NOOP", entity_id=entity.id, reason=f"seen again, unchanged ({entity.state} at {entity.location})")


def add_fields(obs: ObjectObservation) -> dict[str, str]:
    return {"state": obs.state or NEW_STATE, "location": obs.location, "held_by": obs.held_by or "", **obs.attributes()}


@dataclass
class EditResult:
    ops: list[tuple[EditOp, ObjectObservation]]
    events: list[dict]
    touched: set[str]
    added: list[str]


class EntityEditor:
    """Holds one participant's registry and applies a policy's decisions to it."""

    def __init__(self, participant: str, policy: EditPolicy | None = None, embed=None,
                 prompt_budget: int = DEFAULT_PROMPT_BUDGET, entities: list[EntityState] | None = None,
                 next_ord: int = 0):
        self.participant = participant
        self.policy = policy or DeterministicPolicy()
        self._embed = embed
        self.prompt_budget = prompt_budget
        self.entities: dict[str, EntityState] = {e.id: e for e in entities or []}
        self._ord = next_ord
        self._raw_seq = 0
        self.repairs = PerceptionRepairs() if wants_repairs(self.policy) else None

    def embed(self, text: str) -> np.ndarray:
        if self._embed is None:
            raise RuntimeError("this editor has no embedder; pass embed=")
        return self._embed(text)

    def live(self) -> list[EntityState]:
        return [e for e in self.entities.values() if e.status == "active"]

    def active_of_kinds(self, kinds: set[str]) -> list[EntityState]:
        """The active entities of these kinds (what a deterministic edit of observations of
        these kinds may change), from the live index: numpy passes, not a loop over the registry."""
        index = self._live_index()
        return [e for k in sorted(kinds) for e in index.of_kind(k)]

    def _live_index(self) -> _LiveIndex:
        """The registry's live rows, kept up to date by `_apply` (rebuilt when `entities` was
        replaced or grew behind the editor's back, as a resumed build does)."""
        index = getattr(self, "_index", None)
        if index is None or index.source is not self.entities or index.seen != len(self.entities):
            index = self._index = _LiveIndex(self.entities, self._vector if self._embed is not None else None)
        return index

    def _vector(self, e: EntityState) -> np.ndarray:
        return e.emb if e.emb is not None else self.embed(e.identity_text())

    def candidates(self, obs: ObjectObservation) -> list[EntityState]:
        """The registry slice a decision may use: all of it within the prompt budget, else the
        `prompt_budget` nearest by embedding plus every entity with the same normalized name
        (in registry order). Costs numpy work over the live rows, not Python work
        per entity: a 1,000-hour memory holds tens of thousands of entities."""
        index = self._live_index()
        if getattr(self.policy, "same_kind_only", False):
            return index.of_kind(obs.kind)  # what the wider slice comes to after the policy's own filter
        if index.count <= self.prompt_budget or self._embed is None:
            return index.live()
        return index.nearest(self.embed(identity_text(obs.name, obs.category)), self.prompt_budget, obs.kind)

    def edit(self, segment: LayeredSegment) -> EditResult:
        cands = [self.candidates(o) for o in segment.objects]
        decisions = self.policy.decide(segment, segment.objects, cands, self.embed if self._embed else None)
        if len(decisions) != len(segment.objects):
            raise ValueError(f"policy {self.policy.name} returned {len(decisions)} decisions for {len(segment.objects)} observations")
        result = EditResult(ops=[], events=[], touched=set(), added=[])
        added_here: dict[str, list[str]] = {}
        for obs, ops in zip(segment.objects, decisions):
            note = ""
            if self.repairs is not None:
                found = self.repairs.alias_target(obs, segment, self._live_index().of_kind, self.entities)
                if found is not None:  # form/repair.py: the held object under a second name
                    target, note = found
                    obs = obs.model_copy(update={"object_id": target.object_id, "kind": target.kind,
                                                 "name": target.name, "category": target.category,
                                                 "visual_properties": type(obs.visual_properties)()})
                    ops = [update_or_noop(target, obs)]
            for op in ops:
                op = self._repair(op, obs, added_here)
                if op is not None and note:
                    op = op.model_copy(update={"reason": f"{op.reason} {note}"})
                if op is not None:
                    self._apply(op, obs, segment, result, added_here)
        return result

    def _repair(self, op: EditOp, obs: ObjectObservation, added_here) -> EditOp | None:
        """Make a decision applicable: ADD on a known id becomes UPDATE, UPDATE/DELETE/NOOP on
        an unknown id becomes ADD (the observation must land somewhere)."""
        same_turn = [self.entities[i] for i in added_here.get(obs.kind, []) if self.entities[i].status == "active"]
        same_turn = [e for e in same_turn if compatible(e, obs.attributes())]
        if op.op == "ADD" and same_turn and not isinstance(self.policy, RawPolicy):
            # The same object twice in one turn: the second sighting edits the first record.
            fixed = update_or_noop(same_turn[-1], obs)
            return fixed.model_copy(update={"reason": fixed.reason + " [repair: added earlier in this turn]"})
        if op.op == "ADD" and op.entity_id in self.entities and self.entities[op.entity_id].status == "active":
            return op.model_copy(update={"op": "UPDATE", "reason": op.reason + " [repair: ADD on existing id]"})
        stale = op.entity_id not in self.entities or self.entities[op.entity_id].status != "active"
        if op.op == "DELETE" and op.merged_into and (stale or self.entities.get(op.merged_into) is None
                                                    or self.entities[op.merged_into].status != "active"):
            return None  # DELETE_INVALID: already retracted earlier in this turn; nothing to do
        if op.op != "ADD" and stale:
            return EditOp(op="ADD", entity_id="", reason=f"{op.reason} [repair: {op.op} on unknown id]", changes=add_fields(obs))
        return op

    def _new_id(self, obs: ObjectObservation, segment: LayeredSegment) -> str:
        if isinstance(self.policy, RawPolicy):
            self._raw_seq += 1
            return f"{self.participant}:{obs.object_id}@{segment.video_id}#{segment.turn_id}.{self._raw_seq}"
        base = f"{self.participant}:{obs.object_id}"
        if base not in self.entities:
            return base
        n = 2
        while f"{base}#{n}" in self.entities:
            n += 1
        return f"{base}#{n}"

    def _apply(self, op: EditOp, obs: ObjectObservation, seg: LayeredSegment, result: EditResult, added_here) -> None:
        t = seg.t_start + obs.t_rel
        if op.op == "ADD":
            eid = self._new_id(obs, seg)
            props = obs.attributes()
            e = EntityState(
                id=eid, participant=self.participant, object_id=obs.object_id, kind=obs.kind,
                name=obs.name, category=obs.category, is_fixture=obs.is_fixture,
                state=obs.state or NEW_STATE, location=obs.location, held_by=obs.held_by or "",
                first_seen=t, first_video=seg.video_id, first_turn=seg.turn_id,
                **{k: props.get(k, "") for k in ATTRS},
            )
            if self._embed is not None:
                e.emb = self.embed(e.identity_text())
            index = self._live_index()
            self.entities[eid] = e
            index.add(e)
            result.added.append(eid)
            added_here.setdefault(obs.kind, []).append(eid)
            op = op.model_copy(update={"entity_id": eid})
            prev_state = prev_loc = ""
        else:
            e = self.entities[op.entity_id]
            prev_state, prev_loc = e.state, e.location
            if op.op == "UPDATE":
                for k, v in op.changes.items():
                    if k in ("state", "location", "held_by") or k in ATTRS:
                        setattr(e, k, v)
            elif op.op == "DELETE":
                if e.status == "active":
                    self._live_index().remove(e.id)
                e.status = "merged" if op.merged_into else "deleted"
                e.merged_into = op.merged_into or ""
                e.state = op.changes.get("state", e.state)
        if op.op == "DELETE" and op.merged_into:
            # The duplicate's retraction is its own decision; the observation goes to the keeper.
            result.ops.append((op, obs))
            result.touched.add(e.id)
            return
        restore = self.repairs.implied_event(e, obs, t) if self.repairs is not None else None
        if restore is not None:  # form/repair.py: a state change the next step implies was missed
            state, when = restore
            self._ord += 1
            result.events.append({
                "id": f"{e.id}@{self._ord}", "participant": self.participant, "entity": e.id,
                "video": seg.video_id, "turn": seg.turn_id, "t": round(when, 3), "ord": self._ord,
                "state": state, "location": e.location, "prev_state": prev_state, "prev_location": prev_loc,
                "zone": "", "held_by": e.held_by, "relative_to": "", "relation": "", "action": "",
                "narration": f"(restored: '{obs.narration}' implies it was {state})", "op": "UPDATE",
                "segment": seg.segment_id,
            })
        e.last_seen, e.last_video, e.last_turn = t, seg.video_id, seg.turn_id
        e.n_observations += 1
        if self.repairs is not None:
            self.repairs.note(e)
        result.touched.add(e.id)
        result.ops.append((op, obs))
        self._ord += 1
        result.events.append({
            "id": f"{e.id}@{self._ord}", "participant": self.participant, "entity": e.id,
            "video": seg.video_id, "turn": seg.turn_id, "t": round(t, 3), "ord": self._ord,
            "state": obs.state or e.state, "location": obs.location, "prev_state": prev_state,
            "prev_location": prev_loc, "zone": obs.zone, "held_by": obs.held_by or "",
            "relative_to": obs.relative_to, "relation": obs.relation, "action": obs.action,
            "narration": obs.narration, "op": op.op, "segment": seg.segment_id,
        })


class _LiveIndex:
    """The live entities as rows, in registry order: their identity vectors in one growing
    matrix, their kinds as codes and a live mask, so a candidate slice is a few numpy passes
    instead of a Python loop and a fresh stack of every vector for each segment (which made a
    build's cost per hour grow with the number of entities)."""

    def __init__(self, entities: dict[str, EntityState], vector: Callable[[EntityState], np.ndarray] | None):
        self.source, self.seen = entities, 0
        self._vector = vector
        self._rows: list[EntityState] = []
        self._row_of: dict[str, int] = {}
        self._kinds: dict[str, int] = {}
        self._kind = np.zeros(64, dtype=np.int32)
        self._alive = np.zeros(64, dtype=bool)
        self._matrix: np.ndarray | None = None
        self.count = 0
        for e in entities.values():
            self.seen += 1
            if e.status == "active":
                self._append(e)

    def _append(self, e: EntityState) -> None:
        n = len(self._rows)
        if n == len(self._alive):  # grow by doubling
            self._kind = np.concatenate([self._kind, np.zeros(n, dtype=np.int32)])
            self._alive = np.concatenate([self._alive, np.zeros(n, dtype=bool)])
            if self._matrix is not None:
                self._matrix = np.concatenate([self._matrix, np.zeros_like(self._matrix)])
        if self._vector is not None:
            v = np.asarray(self._vector(e), dtype=np.float32)
            if self._matrix is None:
                self._matrix = np.zeros((len(self._alive), v.shape[0]), dtype=np.float32)
            self._matrix[n] = v
        self._kind[n] = self._kinds.setdefault(e.kind, len(self._kinds))
        self._alive[n] = True
        self._rows.append(e)
        self._row_of[e.id] = n
        self.count += 1

    def add(self, e: EntityState) -> None:
        self.seen += 1
        if e.status == "active":
            self._append(e)

    def remove(self, entity_id: str) -> None:
        row = self._row_of.pop(entity_id, None)
        if row is not None and self._alive[row]:
            self._alive[row] = False
            self.count -= 1

    def live(self) -> list[EntityState]:
        n = len(self._rows)
        return [self._rows[i] for i in np.flatnonzero(self._alive[:n])]

    def of_kind(self, kind: str) -> list[EntityState]:
        """Every live row of `kind`, in registry order."""
        code = self._kinds.get(kind)
        if code is None:
            return []
        n = len(self._rows)
        return [self._rows[i] for i in np.flatnonzero(self._alive[:n] & (self._kind[:n] == code))]

    def nearest(self, q: np.ndarray, k: int, kind: str) -> list[EntityState]:
        """The `k` live rows nearest to `q` (ties by registry order, as a stable sort takes them)
        and every live row of `kind`, in registry order."""
        n = len(self._rows)
        alive = self._alive[:n]
        sims = np.where(alive, self._matrix[:n] @ np.asarray(q, dtype=np.float32), -np.inf)
        keep = np.zeros(n, dtype=bool)
        if k >= self.count:
            keep[alive] = True
        else:
            neg = -sims
            kth = np.partition(neg, k - 1)[k - 1]
            above = np.flatnonzero(neg < kth)
            ties = np.flatnonzero(neg == kth)
            keep[above] = True
            keep[ties[: k - len(above)]] = True
        code = self._kinds.get(kind)
        if code is not None:
            keep |= alive & (self._kind[:n] == code)
        return [self._rows[i] for i in np.flatnonzero(keep & alive)]
