"""The participant memory slice that consolidation reads: segments and narrated steps.

A step is one narrated action as the formed memory holds it: the state-history entries that one
narration wrote (same video, time and narration), the first being the main object. Everything
the processors cite (segment ids, entity ids) comes from here, so it exists in the bank.
"""

from __future__ import annotations

import sys
from array import array
from collections.abc import Mapping
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


class ParticipantMemory:
    """A participant's segments and narrated steps.

    Given as lists (the tests, the live path) or, as `load_memory` reads them, as a segment frame
    and a `StepTable`: then each video's steps are made when they are read (`steps_by_video()`,
    `iter_steps()`) and dropped after, and the segment rows stay columns until a caller asks for
    them as dicts (`segments`, which the model-backed processors read). At 1,000 h the steps as
    objects and the segments as dicts were ~1 GB held through the whole consolidation."""

    def __init__(self, participant: str, segments: list[dict] | None = None, steps: list[MemoryStep] | None = None, *,
                 segment_frame=None, table: StepTable | None = None):
        self.participant = participant
        self._segments = segments
        self._frame = segment_frame
        self._steps = steps
        self._table = table
        self._by_video: dict[str, list[MemoryStep]] | None = None

    @property
    def segments(self) -> list[dict]:
        if self._segments is None:
            self._segments = self._frame.to_dicts() if self._frame is not None else []
        return self._segments

    @property
    def steps(self) -> list[MemoryStep]:
        if self._steps is None:
            return list(self.iter_steps())
        return self._steps

    def iter_steps(self):
        """Every step in order (a table's made a video at a time)."""
        if self._table is not None:
            for i in range(len(self._table.videos)):
                yield from self._table.steps_at(i)
        else:
            yield from self._steps or ()

    @property
    def videos(self) -> list[str]:
        if self._segments is None and self._frame is not None:
            return sorted(set(self._frame.get_column("video").to_list()))
        return sorted({s["video"] for s in self.segments})

    def steps_by_video(self):
        """video -> its steps, in order (a mapping that makes a video's steps when read, for a table)."""
        if self._table is not None:
            return self._table
        if self._by_video is None:
            self._by_video = {}
            for s in self._steps or ():
                self._by_video.setdefault(s.video, []).append(s)
        return self._by_video

    def tokens(self) -> set[str]:
        """The distinct step tokens (verb:main kind)."""
        if self._table is not None:
            return set(self._table.tokens)
        return {s.token for s in self.iter_steps()}

    @property
    def segment_ids(self) -> set[str]:
        if self._segments is None and self._frame is not None:
            return set(self._frame.get_column("id").to_list())
        return {s["id"] for s in self.segments}


class StepTable(Mapping):
    """A participant's steps as columns (`array` of indexes into one string table, times as
    doubles, each distinct object list once), video by video; read as a mapping video -> the
    video's steps as `MemoryStep`s, made anew on each read (equal to the ones `StepReader.read`
    makes)."""

    _COLUMNS = ("segment", "verb", "objects", "location", "zone", "destination", "relation", "narration")

    def __init__(self):
        self.videos: list[str] = []
        self.index: dict[str, int] = {}
        self.bounds = array("q", [0])  # steps of video i: bounds[i]:bounds[i + 1]
        self.t = array("d")
        self.cols = {name: array("i") for name in self._COLUMNS}
        self.strings: list[str] = []
        self.objsets: list[tuple[Obj, ...]] = []
        self.tokens: list[str] = []  # the distinct tokens
        self._codes: dict[str, int] | None = {}
        self._objcodes: dict[tuple, int] | None = {}
        self._tokcodes: set[str] | None = set()

    def code(self, value: str) -> int:
        n = self._codes.get(value)
        if n is None:
            n = self._codes[value] = len(self.strings)
            self.strings.append(value)
        return n

    def add(self, video: str, segment: str, t: float, verb: str, objects: list[Obj], location: str, zone: str,
            destination: str, relation: str, narration: str) -> None:
        if not self.videos or self.videos[-1] != video:
            if self.videos:
                self.bounds.append(len(self.t))
            self.index[video] = len(self.videos)
            self.videos.append(video)
        key = tuple(objects)
        o = self._objcodes.get(key)
        if o is None:
            o = self._objcodes[key] = len(self.objsets)
            self.objsets.append(key)
        token = f"{verb}:{objects[0].kind}"
        if token not in self._tokcodes:
            self._tokcodes.add(token)
            self.tokens.append(sys.intern(token))
        self.t.append(t)
        c, code = self.cols, self.code
        for name, value in (("segment", segment), ("verb", verb), ("location", location), ("zone", zone),
                            ("destination", destination), ("relation", relation), ("narration", narration)):
            c[name].append(code(value))
        c["objects"].append(o)

    def close(self) -> StepTable:
        """Done adding: the lookup tables that only adding needs are dropped."""
        if self.videos:
            self.bounds.append(len(self.t))
        self._codes = self._objcodes = self._tokcodes = None
        return self

    def steps_at(self, i: int) -> list[MemoryStep]:
        a, b = self.bounds[i], self.bounds[i + 1]
        s, objsets, video, c = self.strings, self.objsets, self.videos[i], self.cols
        return [MemoryStep(video, s[g], t, s[v], list(objsets[o]), s[lo], s[z], s[d], s[r], s[n])
                for g, t, v, o, lo, z, d, r, n in zip(
                    c["segment"][a:b], self.t[a:b], c["verb"][a:b], c["objects"][a:b], c["location"][a:b], c["zone"][a:b],
                    c["destination"][a:b], c["relation"][a:b], c["narration"][a:b])]

    def __getitem__(self, video: str) -> list[MemoryStep]:
        return self.steps_at(self.index[video])

    def __iter__(self):
        return iter(self.videos)

    def __len__(self) -> int:
        return len(self.videos)


# segments (~ state events / 3.5) per read of the state history: a participant is read a batch of
# videos at a time, so the rows Kùzu and Arrow hold at once are bounded (at 1,000 h the whole
# history at once was over a million rows, gigabytes beside the steps made from them; what a read
# leaves resident grows with its batch: at 100 h `load_memory` rose +229 MB with 40,000, +88 with 10,000)
EVENT_BATCH_SEGMENTS = 10_000


def load_memory(store: Store, participant: str) -> ParticipantMemory:
    segments = store.run("_consolidate_segments", participant=participant)
    # who each merged duplicate was merged into (the entities a step names resolve through it)
    merged = merged_map(store, participant)
    per_video: dict[str, int] = {}
    for video in segments.get_column("video").to_list():
        per_video[video] = per_video.get(video, 0) + 1
    table = StepReader(merged).read_table(store, participant, per_video)
    return ParticipantMemory(participant, segment_frame=segments, table=table)


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
        self._read(store, participant, sizes, lambda *fields: steps.append(MemoryStep(*fields)))
        return steps

    def read_table(self, store: Store, participant: str, sizes: dict[str, int]) -> StepTable:
        """`read`'s steps as a `StepTable`."""
        table = StepTable()
        self._read(store, participant, sizes, table.add)
        return table.close()

    def _read(self, store: Store, participant: str, sizes: dict[str, int], add) -> None:
        for videos in _batches(sizes):
            events = store.run("_consolidate_events_of", participant=participant, videos=videos)
            # ordered here, not by Kùzu: its ORDER BY was seen to return one row of 11,757 out of place (a
            # 10 h synthetic participant; where depends on how the rows lie on disk), which moved a
            # narration's entries apart and changed a routine; (video, t, ord) is unique. The batches
            # are runs of sorted videos, so the steps come in the participant's (video, t, ord) order.
            events = events.sort("video", "t", "ord", maintain_order=True)
            self._steps(events, add)
            del events

    def _steps(self, events, add) -> None:
        """Calls `add(video, segment, t, verb, objects, location, zone, destination, relation,
        narration)` once per step, after its last entry."""
        objs, one, merged = self.objs, self.one, self.merged
        current: list | None = None  # the step being read, as add's arguments
        key = None
        raw = None
        for e in events.iter_rows(named=True):  # one narration's entries are adjacent
            k = (e["video"], e["t"], e["narration"])
            if raw is None or e["video"] != current[0]:
                raw = self.raw.setdefault(e["video"], set())
            raw.add(e["entity"])
            okey = (e["kind"] or "object", resolve(merged, e["entity"]), e["category"] or "", bool(e["is_fixture"]))
            obj = objs.get(okey)
            if obj is None:
                obj = objs[okey] = Obj(*okey)
            if k != key:
                if current is not None:
                    add(*current)
                current = [one(e["video"]), e["segment"], float(e["t"]), one(e["action"]), [obj], one(e["location"]),
                           one(e["zone"]), one(e["relative_to"]), one(e["relation"]), e["narration"] or ""]
                key = k
            elif obj.kind not in {o.kind for o in current[4]}:
                current[4].append(obj)
        if current is not None:
            add(*current)


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
