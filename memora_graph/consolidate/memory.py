"""The participant memory slice that consolidation reads: segments and narrated steps.

A step is one narrated action as the formed memory holds it: the state-history entries that one
narration wrote (same video, time and narration), the first being the main object. Everything
the processors cite (segment ids, entity ids) comes from here, so it exists in the bank.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

from memora_graph.consolidate import vocab
from memora_graph.store import Store

_PREP = {"INSIDE": "in", "ON_TOP_OF": "on", "ADJACENT_TO": "next to", "BELOW": "under", "ABOVE": "above",
         "BEHIND": "behind", "IN_FRONT_OF": "in front of", "LEFT_OF": "left of", "RIGHT_OF": "right of"}


def display(kind: str) -> str:
    return kind.replace("_", " ").strip()


@dataclass(frozen=True, slots=True)
class Obj:
    kind: str
    entity: str  # the entity id (a merged duplicate resolves to what it was merged into)
    category: str
    is_fixture: bool


@dataclass(slots=True)
class MemoryStep:  # slots: a 1,000 h participant has about a million steps
    video: str
    segment: str
    t: float
    verb: str  # EPIC verb class key ("take", "wash", "turn-on")
    objects: list[Obj]
    location: str  # place id of the main object
    zone: str
    destination: str  # what the main object was put in / on (a kind), if narrated
    relation: str
    narration: str
    _text: str | None = field(default=None, repr=False, compare=False)

    @property
    def main(self) -> Obj:
        return self.objects[0]

    @property
    def token(self) -> str:  # interned: the recurring n-grams of a long participant are keyed by tuples of them
        return sys.intern(f"{self.verb}:{self.main.kind}")

    @property
    def is_filler(self) -> bool:
        return self.verb in vocab.FILLER

    def text(self) -> str:
        if self._text is None:
            words = f"{vocab.phrase(self.verb)} {display(self.main.kind)}"
            if self.destination and self.destination != self.main.kind:
                words += f" {_PREP.get(self.relation, 'to')} {display(self.destination)}"
            self._text = words
        return self._text

    def action(self):
        """The step as classes (verb class key, object kind, where it went or happened)."""
        from memora_graph.consolidate.records import StepAction

        return StepAction(verb=self.verb, noun=self.main.kind, place=self.where()[0])

    def where(self) -> tuple[str, str]:
        """(preferred-location words, place id) for where the main object ended up."""
        if self.destination and self.destination != self.main.kind:
            return display(self.destination), self.location
        if self.zone:
            return display(self.zone), self.location
        return display(self.location), self.location


@dataclass
class ParticipantMemory:
    participant: str
    segments: list[dict] = field(default_factory=list)
    steps: list[MemoryStep] = field(default_factory=list)
    _by_video: dict[str, list[MemoryStep]] | None = field(default=None, repr=False)

    @property
    def videos(self) -> list[str]:
        return sorted({s["video"] for s in self.segments})

    def steps_by_video(self) -> dict[str, list[MemoryStep]]:
        if self._by_video is None:
            self._by_video = {}
            for s in self.steps:
                self._by_video.setdefault(s.video, []).append(s)
        return self._by_video

    @property
    def segment_ids(self) -> set[str]:
        return {s["id"] for s in self.segments}


# segments (~ state events / 3.5) per read of the state history: a participant is read a batch of
# videos at a time, so the rows Kùzu and Arrow hold at once are bounded (at 1,000 h the whole
# history at once was over a million rows, gigabytes beside the steps made from them)
EVENT_BATCH_SEGMENTS = 40_000


def load_memory(store: Store, participant: str) -> ParticipantMemory:
    segments = store.run("_consolidate_segments", participant=participant).to_dicts()
    # who each merged duplicate was merged into (the entities a step names resolve through it)
    merged = merged_map(store, participant)
    per_video: dict[str, int] = {}
    for g in segments:
        per_video[g["video"]] = per_video.get(g["video"], 0) + 1
    steps = StepReader(merged).read(store, participant, per_video)
    return ParticipantMemory(participant, segments, steps)


def merged_map(store: Store, participant: str) -> dict[str, str]:
    """Who each merged duplicate (with narrated steps) was merged into."""
    return dict(store.run("_consolidate_merged", participant=participant).iter_rows())


def resolve(merged: dict[str, str], entity: str) -> str:
    """What an entity is now: followed through the merges (a cycle stops where it closes)."""
    seen = set()
    while entity in merged and entity not in seen:
        seen.add(entity)
        entity = merged[entity]
    return entity


class StepReader:
    """Reads narrated steps from the state history, some videos at a time, sharing one `Obj` per
    distinct object and one str per distinct short value; `raw[video]` collects the entity ids
    each video's events name before resolution (what a later merge can re-identify)."""

    def __init__(self, merged: dict[str, str]):
        self.merged = merged
        self.objs: dict[tuple, Obj] = {}
        self.text: dict[str, str] = {}
        self.raw: dict[str, set[str]] = {}

    def one(self, value: str | None) -> str:
        value = value or ""
        return self.text.setdefault(value, value)

    def read(self, store: Store, participant: str, sizes: dict[str, int]) -> list[MemoryStep]:
        """The steps of the videos in `sizes` (video -> rows, to batch the reads by), in
        (video, t, ord) order."""
        steps: list[MemoryStep] = []
        for videos in _batches(sizes):
            events = store.run("_consolidate_events_of", participant=participant, videos=videos)
            # ordered here, not by Kùzu: its ORDER BY was seen to return one row of 11,757 out of place (a
            # 10 h synthetic participant; where depends on how the rows lie on disk), which moved a
            # narration's entries apart and changed a routine; (video, t, ord) is unique. The batches
            # are runs of sorted videos, so the steps come in the participant's (video, t, ord) order.
            events = events.sort("video", "t", "ord", maintain_order=True)
            self._steps(events, steps)
            del events
        return steps

    def _steps(self, events, steps: list[MemoryStep]) -> None:
        objs, one, merged = self.objs, self.one, self.merged
        current: MemoryStep | None = None
        key = None
        raw = None
        for e in events.iter_rows(named=True):  # one narration's entries are adjacent
            k = (e["video"], e["t"], e["narration"])
            if raw is None or e["video"] != current.video:
                raw = self.raw.setdefault(e["video"], set())
            raw.add(e["entity"])
            okey = (e["kind"] or "object", resolve(merged, e["entity"]), e["category"] or "", bool(e["is_fixture"]))
            obj = objs.get(okey)
            if obj is None:
                obj = objs[okey] = Obj(*okey)
            if k != key:
                current = MemoryStep(video=one(e["video"]), segment=e["segment"], t=float(e["t"]), verb=one(e["action"]),
                                     objects=[obj], location=one(e["location"]), zone=one(e["zone"]),
                                     destination=one(e["relative_to"]), relation=one(e["relation"]),
                                     narration=e["narration"] or "")
                steps.append(current)
                key = k
            elif obj.kind not in {o.kind for o in current.objects}:
                current.objects.append(obj)


def _batches(per_video: dict[str, int]) -> list[list[str]]:
    """The videos in order, in runs of about EVENT_BATCH_SEGMENTS segments (or rows)."""
    out: list[list[str]] = []
    size = 0
    for video in sorted(per_video):
        if not out or size + per_video[video] > EVENT_BATCH_SEGMENTS:
            out.append([])
            size = 0
        out[-1].append(video)
        size += per_video[video]
    return out
