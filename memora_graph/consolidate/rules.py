"""The deterministic consolidation and enrichment policies (the CPU default).

Consolidation reads each completed video's narrated steps and counts what it shows: where each
object ends up (storage preferences, by context), what the person does right after an action
(organizational habits), how a kind of object flows from use to its place (workflow patterns),
and the short action sequences it contains. The participant pass keeps what repeats in at least
`min_videos` videos. Enrichment cuts videos into episodes, groups episodes with the same goal
across videos into routine skills (canonical steps from the most typical episode), and turns
repeated instrument choices ("stir egg in pan using spatula") into generated preferences with
keywords. Every record cites the segments it was counted from.
"""

from __future__ import annotations

import hashlib
import math
from collections import Counter, defaultdict

import numpy as np

from memora_graph.consolidate import vocab
from memora_graph.consolidate.memory import ParticipantMemory, MemoryStep, display
from memora_graph.consolidate.records import (
    ActionSequence, Consolidation, Enrichment, Episode, GeneratedPreference, OrganizationalHabit, RoutineSkill, StepAction,
    StoragePreference, VideoConsolidation, WorkflowPattern,
)
from memora_graph.sequences import lcs_length
from memora_graph.text import uniq as _uniq


def _conf(x: float) -> float:
    return round(min(max(x, 0.0), 0.99), 3)


def _support(videos: int) -> float:
    """How much repetition across videos is worth: 0.5, 0.75, 0.875, ... for 1, 2, 3 videos."""
    return 1.0 - 0.5 ** max(videos, 0)


_ON = frozenset({"rack", "top", "counter", "board", "hob", "tray", "table", "plate", "worktop", "shelf", "stove"})


def _prep(location_words: str) -> str:
    return "on" if _ON & set(location_words.split()) else "in"


def stable_id(participant: str, kind: str, *key) -> str:
    digest = hashlib.blake2b("\x1f".join(map(str, key)).encode(), digest_size=5).hexdigest()
    return f"{participant}:{kind}:{digest}"


class RuleConsolidator:
    """Offline consolidation: per completed video, then what repeats across videos."""

    name = "deterministic"
    min_videos = 2
    habit_window = 30.0  # seconds: the next action must follow within this
    habit_min_count = 3
    habit_min_share = 0.25
    workflow_window = 120.0  # seconds from the use of an object to where it is put
    workflow_min_count = 3
    sequence_lengths = (3, 4, 5)
    sequence_span = 60.0  # seconds an action sequence may span
    # At most this many records of each kind per participant, the best supported first: every record
    # costs an embedding at build time and a line in an agent's context at read time.
    caps = {"storage": 10, "after_use": 10, "during_use": 6, "default": 4, "habit": 15, "workflow": 10, "sequence": 12}

    def __init__(self):
        self._recurring: tuple[int, set[tuple[str, ...]]] | None = None

    # -- per video ---------------------------------------------------------------------
    def consolidate_video(self, memory: ParticipantMemory, video: str) -> VideoConsolidation:
        steps = memory.steps_by_video().get(video, [])
        return VideoConsolidation(
            video=video, storage_preferences=self.video_storage(video, steps), organizational_habits=self.video_habits(video, steps),
            workflow_patterns=self.video_workflows(video, steps),
            action_sequences=self.video_sequences(video, steps, self.recurring(memory)),
        )

    def video_storage(self, video: str, steps: list[MemoryStep]) -> list[StoragePreference]:
        seen: dict[tuple, dict] = {}
        used: dict[str, bool] = {}

        def note(s: MemoryStep, context: str, where: str, place: str) -> None:
            rec = seen.setdefault((s.main.kind, context, where), {"place": place, "n": 0, "segments": [], "entities": []})
            rec["n"] += 1
            rec["segments"].append(s.segment)
            rec["entities"].append(s.main.entity)

        for s in steps:
            if s.main.is_fixture:
                continue
            kind = s.main.kind
            if s.verb in vocab.RELEASING or s.verb == "insert":
                where, place = s.where()
                if used.get(kind):
                    context = "after_use"
                elif s.destination in vocab.STORAGE_KINDS or s.zone in vocab.STORAGE_ZONES:
                    context = "storage"
                else:
                    context = "default"
                note(s, context, where, place)
                used[kind] = False
            elif s.verb in vocab.TAKING:
                fixture = next((o for o in s.objects[1:] if o.kind in vocab.STORAGE_KINDS), None)
                if fixture is not None:
                    note(s, "storage", display(fixture.kind), s.location)
            elif not s.is_filler:
                note(s, "during_use", display(s.location), s.location)
                used[kind] = True
        totals: Counter[tuple] = Counter()
        for (kind, context, _), rec in seen.items():
            totals[(kind, context)] += rec["n"]
        out = []
        for (kind, context, where), rec in sorted(seen.items()):
            out.append(StoragePreference.model_construct(
                object=kind, object_name=display(kind), preferred_location=where, place=rec["place"], context=context,
                count=rec["n"], total=totals[(kind, context)], alternatives={}, confidence=_conf(rec["n"] / totals[(kind, context)]),
                supporting_episodes=_uniq(rec["segments"]), entities=_uniq(rec["entities"]), videos={video: rec["n"]},
            ))
        return out

    def video_habits(self, video: str, steps: list[MemoryStep]) -> list[OrganizationalHabit]:
        pairs: dict[tuple[str, str], dict] = {}
        triggers: Counter[str] = Counter()
        for i, a in enumerate(steps):
            trigger = f"{vocab.phrase(a.verb)} {display(a.main.kind)}"
            for b in steps[i + 1:]:
                if b.t - a.t > self.habit_window:
                    break
                if b.token == a.token:
                    continue
                if a.is_filler and b.is_filler and a.main.kind == b.main.kind:
                    break  # take X -> put X, open X -> close X: bookkeeping, not a habit
                triggers[trigger] += 1
                rec = pairs.setdefault((trigger, b.text()), {"n": 0, "segments": [], "entities": [], "a": a, "b": b})
                rec["n"] += 1
                rec["segments"] += [a.segment, b.segment]
                rec["entities"] += [a.main.entity, b.main.entity]
                break
        out = []
        for (trigger, nxt), rec in sorted(pairs.items()):
            a, b = rec["a"], rec["b"]
            statement = (f"After {vocab.gerund(a.verb)} the {display(a.main.kind)}, usually "
                         f"{vocab.third_person(vocab.phrase(b.verb))} the {b.text()[len(vocab.phrase(b.verb)) + 1:]}")
            out.append(OrganizationalHabit.model_construct(
                trigger=trigger, next_action=nxt, trigger_step=a.action(), next_step=b.action(),
                habit=statement.replace("  ", " "), count=rec["n"],
                trigger_count=triggers[trigger], objects_involved=_uniq([display(a.main.kind), display(b.main.kind)]),
                confidence=_conf(rec["n"] / triggers[trigger]), supporting_episodes=_uniq(rec["segments"]),
                entities=_uniq(rec["entities"]), videos={video: rec["n"]},
            ))
        return out

    def video_workflows(self, video: str, steps: list[MemoryStep]) -> list[WorkflowPattern]:
        flows: dict[tuple[str, str, str], dict] = {}
        last_use: dict[str, MemoryStep] = {}
        for s in steps:
            if s.main.is_fixture:
                continue
            kind = s.main.kind
            if not s.is_filler and vocab.category(s.verb) in ("cleanup", "prep", "cooking"):
                last_use[kind] = s
            elif (s.verb in vocab.RELEASING or s.verb == "insert") and kind in last_use:
                u = last_use.pop(kind)
                if s.t - u.t > self.workflow_window:
                    continue
                where, _ = s.where()
                if where == display(u.location):
                    continue  # put down where it was used: no flow
                key = (s.main.category or "objects", f"{u.verb} @ {display(u.location)}", f"put {_prep(where)} {where}")
                rec = flows.setdefault(key, {"n": 0, "objects": [], "segments": [], "entities": [], "u": u, "where": where})
                rec["n"] += 1
                rec["objects"].append(display(kind))
                rec["segments"] += [u.segment, s.segment]
                rec["entities"].append(s.main.entity)
        out = []
        for (cat, use, then), rec in sorted(flows.items()):
            u = rec["u"]
            objects = _uniq(rec["objects"])
            out.append(WorkflowPattern.model_construct(
                pattern=f"{cat.capitalize()} ({', '.join(objects[:4])}) are usually {vocab.past_tense(u.verb)} at the "
                        f"{display(u.location)}, then put {_prep(rec['where'])} the {rec['where']}",
                category=cat, use=use, then=then, objects=objects, count=rec["n"], confidence=0.0,
                supporting_episodes=_uniq(rec["segments"]), entities=_uniq(rec["entities"]), videos={video: rec["n"]},
            ))
        return out

    def _windows(self, steps: list[MemoryStep]):
        run: list[MemoryStep] = []
        for s in steps:  # collapse immediate repeats ("move tofu" x 12)
            if not run or run[-1].token != s.token:
                run.append(s)
        for n in self.sequence_lengths:
            for i in range(len(run) - n + 1):
                window = run[i:i + n]
                if window[-1].t - window[0].t > self.sequence_span:
                    continue
                tokens = tuple(s.token for s in window)
                if len(set(tokens)) < n:
                    continue
                if all(s.is_filler for s in window) and len({s.main.kind for s in window}) < 2:
                    continue
                yield tokens, window

    def recurring(self, memory: ParticipantMemory) -> set[tuple[str, ...]]:
        """Action n-grams seen in at least `min_videos` videos: the per-video pass reports only these."""
        if self._recurring is None or self._recurring[0] != id(memory):
            self._recurring = (id(memory), self._recurring_ngrams(memory))
        return self._recurring[1]

    def _recurring_ngrams(self, memory: ParticipantMemory) -> set[tuple[str, ...]]:
        # Each video's distinct n-grams as rows of token numbers (uint16 or uint32, padded with 0),
        # all videos' rows counted at once: a row per n-gram and video, where a dict of every
        # n-gram (a tuple and its count each) took ~1 GB at 1,000 h, most of them seen once.
        tokens = sorted(memory.tokens())
        number = {t: i + 1 for i, t in enumerate(tokens)}
        width = max(self.sequence_lengths)
        dtype = np.uint16 if len(tokens) < 2 ** 16 else np.uint32
        rows = []
        for _, steps in memory.steps_by_video().items():
            found = {tuple(number[t] for t in ngram) for ngram, _ in self._windows(steps)}
            if found:
                rows.append(np.array([g + (0,) * (width - len(g)) for g in found], dtype=dtype))
        if not rows:
            return set()
        every = np.concatenate(rows)
        del rows
        keys = np.ascontiguousarray(every).view(np.dtype((np.void, every.dtype.itemsize * width))).ravel()
        unique, videos = np.unique(keys, return_counts=True)
        kept = unique[videos >= self.min_videos].view(every.dtype).reshape(-1, width)
        return {tuple(tokens[i - 1] for i in row if i) for row in kept.tolist()}

    def _recurring_windows(self, steps: list[MemoryStep], recurring: set[tuple[str, ...]]) -> dict[tuple, list]:
        """One video's windows whose tokens recur, grouped by their tokens in the order first seen: a
        group is one action sequence of the video, its first window gives the sequence's texts."""
        found: dict[tuple[str, ...], list[list[MemoryStep]]] = {}
        for tokens, window in self._windows(steps):
            if tokens in recurring:
                found.setdefault(tokens, []).append(window)
        return found

    def video_sequences(self, video: str, steps: list[MemoryStep], recurring: set[tuple[str, ...]]) -> list[ActionSequence]:
        out = []
        for windows in self._recurring_windows(steps, recurring).values():
            first, n = windows[0], len(windows)
            out.append(self._window_sequence(
                tuple(s.text() for s in first), first, count=n, supporting_episodes=_uniq(w[0].segment for w in windows),
                segments=_uniq(s.segment for w in windows for s in w),
                entities=_uniq(s.main.entity for w in windows for s in w), videos={video: n}))
        return out

    def _sequence_counts(self, steps: list[MemoryStep], recurring: set[tuple[str, ...]]):
        """(steps' texts, count) of each action sequence `video_sequences` would report for one
        video, in its order, without building the records."""
        return [(tuple(s.text() for s in windows[0]), len(windows))
                for windows in self._recurring_windows(steps, recurring).values()]

    def _sequence_evidence(self, video: str, steps: list[MemoryStep], recurring: set[tuple[str, ...]],
                           evidence: dict[tuple[str, ...], _SequenceEvidence]) -> None:
        """What `video_sequences` would cite for one video, added to the chosen sequences' evidence
        (keyed by their steps' texts, as the merge groups them), without building the records.
        Also the video's count of each chosen sequence, and the first window it was seen in."""
        for windows in self._recurring_windows(steps, recurring).values():
            ev = evidence.get(tuple(s.text() for s in windows[0]))
            if ev is None:
                continue
            ev.extend([w[0].segment for w in windows], [s.segment for w in windows for s in w],
                      [s.main.entity for w in windows for s in w])
            ev.videos[video] += len(windows)
            if ev.window is None:
                ev.window = windows[0]

    def _window_sequence(self, steps: tuple[str, ...], window: list[MemoryStep], **evidence) -> ActionSequence:
        """A sequence's record from its first window: the fields `video_sequences` gives it, with
        `evidence` (count, supporting_episodes, segments, entities, videos; none by default)."""
        cats = Counter(vocab.category(s.verb) for s in window if not s.is_filler)
        fields = {"count": 0, "supporting_episodes": [], "segments": [], "entities": [], "videos": {}, **evidence}
        return ActionSequence.model_construct(
            title=" -> ".join(steps), steps=list(steps), actions=[s.action() for s in window],
            activity_type=vocab.ACTIVITY_TYPE[cats.most_common(1)[0][0] if cats else None],
            key_objects=_uniq(display(s.main.kind) for s in window), confidence=0.0, **fields)

    # -- per participant ---------------------------------------------------------------
    def consolidate_participant(self, memory: ParticipantMemory, per_video: list[VideoConsolidation]) -> Consolidation:
        return Consolidation(
            participant=memory.participant, videos=[v.video for v in per_video],
            storage_preferences=self._merged(StoragePreference, _StorageFold, self._choose_storage,
                                             [p for v in per_video for p in v.storage_preferences]),
            organizational_habits=self._merged(OrganizationalHabit, _HabitFold, self._choose_habits,
                                               [h for v in per_video for h in v.organizational_habits]),
            workflow_patterns=self._merged(WorkflowPattern, _WorkflowFold, self._choose_workflows,
                                           [w for v in per_video for w in v.workflow_patterns]),
            action_sequences=self._merge_sequences([a for v in per_video for a in v.action_sequences]),
        )

    def consolidate_streaming(self, memory: ParticipantMemory) -> Consolidation:
        """`consolidate_participant(memory, [consolidate_video(memory, v) for v in memory.videos])`,
        the same records, merged video by video: each video's records are folded into per-key
        counts and videos and dropped (their evidence lists, every segment and entity they were
        counted from, were what grew with the hours: gigabytes at 1,000 h); action sequences are
        only counted (no record is made of them); the few records kept are read again, video by
        video, for their evidence (and a kept sequence for its counts per video and first window)."""
        videos = memory.videos
        by_video = memory.steps_by_video()
        storage, habits, workflows = _StorageFold(), _HabitFold(), _WorkflowFold()
        # action sequences by their steps' texts: [count, videos, the last video]; the records are
        # made for the chosen ones only (a record and a Counter of videos per recurring n-gram were
        # ~1 GB at 1,000 h)
        tally: dict[tuple[str, ...], list] = {}
        recurring = self.recurring(memory)
        for video in videos:
            steps = by_video.get(video, [])
            for p in self.video_storage(video, steps):
                storage.add(p)
            for h in self.video_habits(video, steps):
                habits.add(h)
            for w in self.video_workflows(video, steps):
                workflows.add(w)
            for texts, n in self._sequence_counts(steps, recurring):
                t = tally.get(texts)
                if t is None:
                    t = tally[texts] = [0, 0, None]
                t[0] += n
                if t[2] != video:
                    t[1], t[2] = t[1] + 1, video
        kept_storage = self._choose_storage(storage)
        kept_habits = self._choose_habits(habits)
        kept_workflows = self._choose_workflows(workflows)
        chosen = self._choose_sequence_keys({texts: (t[1], t[0], " -> ".join(texts)) for texts, t in tally.items()
                                             if t[1] >= self.min_videos})
        counts = {texts: tally[texts][0] for texts in chosen}
        del tally
        ev_storage = {key: _Evidence() for key, _ in kept_storage}
        ev_habits = {key: _Evidence() for key, _ in kept_habits}
        ev_workflows = {key: _Evidence() for key, _ in kept_workflows}
        ev_sequences = {steps: _SequenceEvidence() for steps in chosen}
        for video in videos:  # the second read: only the kept records' evidence is gathered
            steps = by_video.get(video, [])
            if ev_storage and any(video in storage.groups[k[:2]][k[2]].videos for k in ev_storage):
                _gather(ev_storage, self.video_storage(video, steps), _StorageFold.key)
            if ev_habits and any(video in habits.groups[k].videos for k in ev_habits):
                _gather(ev_habits, self.video_habits(video, steps), _HabitFold.key)
            if ev_workflows and any(video in workflows.groups[k].videos for k in ev_workflows):
                _gather(ev_workflows, self.video_workflows(video, steps), _WorkflowFold.key)
            if ev_sequences:
                self._sequence_evidence(video, steps, recurring, ev_sequences)
        sequences = []
        for texts in chosen:
            ev = ev_sequences[texts]
            g = _SequenceGroup(self._window_sequence(texts, ev.window))
            g.count, g.videos = counts[texts], ev.videos
            sequences.append(self._merged_sequence(texts, g, ev))
        return Consolidation(
            participant=memory.participant, videos=list(videos),
            storage_preferences=_with_evidence(StoragePreference, kept_storage, ev_storage),
            organizational_habits=_with_evidence(OrganizationalHabit, kept_habits, ev_habits),
            workflow_patterns=_with_evidence(WorkflowPattern, kept_workflows, ev_workflows),
            action_sequences=sequences,
        )

    @staticmethod
    def _merged(record, fold_type, choose, items: list) -> list:
        """The whole-list merge of one kind of record: folded into per-key counts and videos, the
        kept ones chosen from the fold, then their evidence gathered from the items."""
        fold = fold_type()
        for item in items:
            fold.add(item)
        kept = choose(fold)
        evidence = {key: _Evidence() for key, _ in kept}
        _gather(evidence, items, fold_type.key)
        return _with_evidence(record, kept, evidence)

    def _choose_storage(self, fold: _StorageFold) -> list[tuple[tuple, dict]]:
        """The storage preferences kept (their fields but the evidence), best first, by key."""
        out = []
        for (kind, context), locations in fold.groups.items():
            counts = {loc: g.count for loc, g in locations.items()}
            best = min(counts, key=lambda loc: (-counts[loc], loc))
            g = locations[best]
            videos = dict(sorted(g.videos.items()))
            total = sum(counts.values())
            if len(videos) < self.min_videos or counts[best] < (3 if context == "default" else 2):
                continue
            where, place = best, g.first.place
            statement = {
                "storage": f"Typically stores the {display(kind)} {_prep(where)} the {where}",
                "after_use": f"After using the {display(kind)}, usually puts it {_prep(where)} the {where}",
                "during_use": f"Usually uses the {display(kind)} at the {where}",
                "default": f"Usually puts the {display(kind)} {_prep(where)} the {where}",
            }[context]
            out.append(((kind, context, best), dict(
                object=kind, object_name=display(kind), statement=statement, preferred_location=where, place=place,
                context=context, count=counts[best], total=total,
                alternatives={k: v for k, v in sorted(counts.items()) if k != best},
                confidence=_conf(counts[best] / total * _support(len(videos))), videos=videos,
            )))
        out.sort(key=lambda kv: (-kv[1]["count"], kv[1]["object"], kv[1]["context"]))
        kept, per_context = [], Counter()
        for key, p in out:
            per_context[p["context"]] += 1
            if per_context[p["context"]] <= self.caps[p["context"]]:
                kept.append((key, p))
        return kept

    def _choose_habits(self, fold: _HabitFold) -> list[tuple[tuple, dict]]:
        out = []
        for (trigger, nxt), g in fold.groups.items():
            videos = dict(sorted(g.videos.items()))
            count = g.count
            share = count / max(fold.trigger_total[trigger], 1)
            if len(videos) < self.min_videos or count < self.habit_min_count or share < self.habit_min_share:
                continue
            h0 = g.first
            out.append(((trigger, nxt), dict(
                trigger=trigger, next_action=nxt, trigger_step=h0.trigger_step, next_step=h0.next_step,
                habit=h0.habit, count=count, trigger_count=fold.trigger_total[trigger],
                objects_involved=h0.objects_involved, confidence=_conf(share * _support(len(videos))), videos=videos,
            )))
        out.sort(key=lambda kv: (-kv[1]["count"], kv[1]["trigger"], kv[1]["next_action"]))
        return out[: self.caps["habit"]]

    def _choose_workflows(self, fold: _WorkflowFold) -> list[tuple[tuple, dict]]:
        out = []
        for (cat, use, then), g in fold.groups.items():
            videos = dict(sorted(g.videos.items()))
            objects = list(g.extra)
            count = g.count
            if len(videos) < self.min_videos or len(objects) < 2 or count < self.workflow_min_count:
                continue
            head, _, tail = g.first.pattern.partition(") are usually ")
            pattern = f"{cat.capitalize()} ({', '.join(objects[:4])}) are usually {tail}"
            out.append(((cat, use, then), dict(
                pattern=pattern, category=cat, use=use, then=then, objects=objects, count=count,
                confidence=_conf(_support(len(videos)) * min(1.0, len(objects) / 3)), videos=videos,
            )))
        out.sort(key=lambda kv: (-kv[1]["count"], kv[1]["category"], kv[1]["use"]))
        return out[: self.caps["workflow"]]

    def _merge_sequences(self, items: list[ActionSequence]) -> list[ActionSequence]:
        fold = _SequenceFold()
        for a in items:
            fold.add(a)
        chosen = self._choose_sequences(fold)
        evidence = {steps: _SequenceEvidence() for steps in chosen}
        for a in items:
            ev = evidence.get(tuple(a.steps))
            if ev is not None:
                ev.add(a)
        return [self._merged_sequence(steps, fold.groups[steps], evidence[steps]) for steps in chosen]

    def _choose_sequences(self, fold: _SequenceFold) -> list[tuple[str, ...]]:
        """The step sequences kept, best first, from their counts and videos alone."""
        return self._choose_sequence_keys({steps: (len(g.videos), g.count, g.first.title) for steps, g in fold.groups.items()
                                           if len(g.videos) >= self.min_videos})

    def _choose_sequence_keys(self, stats: dict[tuple[str, ...], tuple[int, int, str]]) -> list[tuple[str, ...]]:
        """`_choose_sequences` from each sequence's (videos, count, title)."""
        # Group by the step tokens' text; the same tokens with other destinations are other texts,
        # which is intended: "put bowl on drying rack" and "put bowl in sink" are different habits.
        candidates = {steps: st for steps, st in stats.items() if st[0] >= self.min_videos}
        covered = _longest_cover({steps: st[0] for steps, st in candidates.items()})
        kept = [(steps, st) for steps, st in candidates.items() if covered.get(steps, 0) < st[0]]
        # (a sequence is dropped where a longer one covers every video it is seen in)
        kept.sort(key=lambda ks: (-ks[1][0], -ks[1][1], -len(ks[0]), ks[1][2]))
        out, seen = [], set()
        for steps, _ in kept:  # "wash -> rack -> take" and "take -> wash -> rack" are one loop: keep the best rotation
            loop = (len(steps), frozenset(steps))
            if loop not in seen:
                seen.add(loop)
                out.append(steps)
        return out[: self.caps["sequence"]]

    @staticmethod
    def _merged_sequence(steps: tuple[str, ...], g: _SequenceGroup, ev: _SequenceEvidence) -> ActionSequence:
        a0, n = g.first, len(steps)
        videos = dict(sorted(g.videos.items()))
        return ActionSequence(
            title=a0.title, steps=list(steps), actions=a0.actions, activity_type=a0.activity_type,
            key_objects=a0.key_objects, count=g.count,
            confidence=_conf(_support(len(videos)) * min(1.0, 0.6 + 0.1 * n)),
            supporting_episodes=list(ev.episodes), segments=list(ev.segments), entities=list(ev.entities), videos=videos,
        )


class _Thin:
    """What the merge reads of a key's first record (in video order): its place (storage), its
    steps as classes, statement and objects (habits), its title, actions, activity type and key
    objects (sequences)."""

    __slots__ = ("place", "trigger_step", "next_step", "habit", "objects_involved", "title", "actions", "activity_type",
                 "key_objects")


def _action_key(a: StepAction | None):
    return None if a is None else (a.verb, a.noun, a.place, a.instrument)


class _Rows:
    """One video's records of one kind, compact: per record its merge key (an id into the index's
    key table), count, observations in the video, what the merge reads of it as a first record
    (a tuple shared by every equal one), and its evidence lists as indexes into the video's
    string table (segment and entity ids), one flat array and offsets per list."""

    __slots__ = ("keys", "counts", "seen", "firsts", "evidence", "extra")

    def __init__(self, keys, counts, seen, firsts, evidence, extra=None):
        self.keys, self.counts, self.seen, self.firsts, self.evidence, self.extra = keys, counts, seen, firsts, evidence, extra

    def rows_of(self, key_id: int) -> list[int]:
        return np.flatnonzero(self.keys == key_id).tolist()

    def lists(self, i: int, strings: list[str]):
        """Record `i`'s evidence lists, as strings."""
        return [[strings[x] for x in flat[offsets[i]:offsets[i + 1]].tolist()] for offsets, flat in self.evidence]


class VideoRows:
    """One video's records as `FoldIndex` keeps them: storage preferences, habits and action
    sequences as `_Rows`, workflow patterns (a handful) as records, the video's string table."""

    __slots__ = ("video", "strings", "storage", "habit", "sequence", "workflows")

    def __init__(self, video, strings, storage, habit, sequence, workflows):
        self.video, self.strings, self.workflows = video, strings, workflows
        self.storage, self.habit, self.sequence = storage, habit, sequence


_EVIDENCE_LISTS = {"storage": ("supporting_episodes", "entities"), "habit": ("supporting_episodes", "entities"),
                   "sequence": ("supporting_episodes", "segments", "entities")}


class FoldIndex:
    """`RuleConsolidator.consolidate_participant` kept up to date one video at a time.

    Each video's records are kept compact (`VideoRows`: merge keys as ids into one key table per
    kind, counts in arrays, evidence as indexes into the video's segment and entity ids; a record
    object per n-gram took ~1 GB at 100 h); the folds the merge chooses from (counts and videos
    per key, the first record in video order) are updated by the difference a video makes, so
    replacing one video costs its own records, not every video's. The records chosen and their
    evidence (the union, in video order, of the chosen keys' records) are the batch merge's:
    tests/consolidate and tests/serve compare them."""

    _KINDS = ("storage", "habit", "sequence")

    def __init__(self, rules: RuleConsolidator):
        self.rules = rules
        self.videos: dict[str, VideoRows] = {}
        self.key_ids: dict[str, dict[tuple, int]] = {k: {} for k in self._KINDS}  # kind -> merge key -> id
        self.keys: dict[str, list[tuple]] = {k: [] for k in self._KINDS}  # kind -> id -> merge key
        self.shared: dict = {}  # equal first-record tuples and strings, one object each
        self.steps: dict[tuple, StepAction] = {}
        self.storage, self.habits, self.sequences = _StorageFold(), _HabitFold(), _SequenceFold()
        self.triggers: dict[str, dict[str, int]] = {}  # habit trigger -> {video: its count there}

    # -- compact form ------------------------------------------------------------------------
    def _key_id(self, kind: str, key: tuple) -> int:
        ids = self.key_ids[kind]
        n = ids.get(key)
        if n is None:
            key = tuple(self.share(x) for x in key)
            n = ids[key] = len(self.keys[kind])
            self.keys[kind].append(key)
        return n

    def share(self, key, value=None):
        """The one object kept for `key` (`value`, or the key itself, the first time)."""
        hit = self.shared.get(key)
        if hit is None:
            hit = self.shared[key] = key if value is None else value
        return hit

    def _first_of(self, kind: str, r) -> tuple:
        if kind == "storage":
            return (r.place,)
        if kind == "habit":
            return (_action_key(r.trigger_step), _action_key(r.next_step), r.habit, tuple(r.objects_involved))
        return (r.title, tuple(_action_key(a) for a in r.actions), r.activity_type, tuple(r.key_objects))

    def compact(self, v: VideoConsolidation) -> VideoRows:
        """`v` as the index keeps it."""
        strings: dict[str, int] = {}
        parts = {kind: self._rows(kind, v.video, records, keyf, strings) for kind, records, keyf in self._parts(v)}
        return VideoRows(v.video, list(strings), parts["storage"], parts["habit"], parts["sequence"], list(v.workflow_patterns))

    def _rows(self, kind: str, video: str, records, keyf, strings: dict[str, int]) -> _Rows:
        """Records of one kind as `_Rows`, their evidence strings numbered in `strings` (added to)."""
        lists = _EVIDENCE_LISTS[kind]
        offsets = {name: [0] for name in lists}
        flats = {name: [] for name in lists}
        for r in records:
            for name in lists:
                flat = flats[name]
                flat.extend(strings.setdefault(x, len(strings)) for x in getattr(r, name))
                offsets[name].append(len(flat))
        return _Rows(
            np.array([self._key_id(kind, keyf(r)) for r in records], dtype=np.int32),
            np.array([r.count for r in records], dtype=np.int64),
            np.array([r.videos.get(video, 0) for r in records], dtype=np.int64),
            [self.share(self._first_of(kind, r)) for r in records],
            [(np.array(offsets[n], dtype=np.int32), np.array(flats[n], dtype=np.int32)) for n in lists],
            np.array([h.trigger_count for h in records], dtype=np.int64) if kind == "habit" else None)

    def rows_to_json(self, rows: VideoRows, firsts: dict) -> dict:
        """One video's rows as JSON: merge keys as ids into `tables_to_json`'s key tables, first
        records as ids into `firsts` (added to: first record -> id)."""
        out = {"video": rows.video, "strings": rows.strings, "workflows": [w.model_dump(mode="json") for w in rows.workflows]}
        for kind in self._KINDS:
            part = getattr(rows, kind)
            out[kind] = [part.keys.tolist(), part.counts.tolist(), part.seen.tolist(),
                         [firsts.setdefault(f, len(firsts)) for f in part.firsts],
                         [[o.tolist(), f.tolist()] for o, f in part.evidence], None if part.extra is None else part.extra.tolist()]
        return out

    def tables_to_json(self, firsts: dict) -> dict:
        return {"keys": {kind: self.keys[kind] for kind in self._KINDS}, "firsts": list(firsts)}

    def tables_from_json(self, d: dict) -> dict:
        """`tables_to_json`'s document as `rows_from_json` reads it (this index's key ids)."""
        return {"keys": {kind: np.array([self._key_id(kind, tuple(k)) for k in d["keys"][kind]], dtype=np.int32)
                         for kind in self._KINDS},
                "firsts": [self.share(_tuples(f)) for f in d["firsts"]]}

    def rows_from_json(self, d: dict, tables: dict) -> VideoRows:
        """`rows_to_json`'s document as the index keeps it (`tables`: `tables_from_json`)."""
        parts = {}
        for kind in self._KINDS:
            keys, counts, seen, firsts, evidence, extra = d[kind]
            parts[kind] = _Rows(
                tables["keys"][kind][np.array(keys, dtype=np.int64)], np.array(counts, dtype=np.int64),
                np.array(seen, dtype=np.int64), [tables["firsts"][f] for f in firsts],
                [(np.array(o, dtype=np.int32), np.array(f, dtype=np.int32)) for o, f in evidence],
                None if extra is None else np.array(extra, dtype=np.int64))
        workflows = [WorkflowPattern.model_construct(**w) for w in d["workflows"]]
        return VideoRows(d["video"], d["strings"], parts["storage"], parts["habit"], parts["sequence"], workflows)

    def step_action(self, key) -> StepAction | None:
        """The one StepAction kept for (verb, noun, place, instrument)."""
        if key is None:
            return None
        a = self.steps.get(key)
        if a is None:
            verb, noun, place, instrument = key
            a = self.steps[key] = (StepAction(verb=verb, noun=noun, place=place, instrument=instrument) if instrument
                                   else StepAction(verb=verb, noun=noun, place=place))
        return a

    def _thin(self, kind: str, rows: _Rows, i: int) -> _Thin:
        t, first = _Thin(), rows.firsts[i]
        if kind == "storage":
            t.place = first[0]
        elif kind == "habit":
            t.trigger_step, t.next_step = self.step_action(first[0]), self.step_action(first[1])
            t.habit, t.objects_involved = first[2], list(first[3])
        else:
            t.title, t.actions = first[0], [self.step_action(a) for a in first[1]]
            t.activity_type, t.key_objects = first[2], list(first[3])
        return t

    # -- the merge kept up to date -------------------------------------------------------------
    @staticmethod
    def _parts(v: VideoConsolidation):
        return (("storage", v.storage_preferences, _StorageFold.key), ("habit", v.organizational_habits, _HabitFold.key),
                ("sequence", v.action_sequences, lambda a: tuple(a.steps)))

    def _table(self, kind: str, key, create: bool):
        if kind == "storage":
            table = self.storage.groups.setdefault(key[:2], {}) if create else self.storage.groups.get(key[:2], {})
            return table, key[2]
        return (self.habits.groups if kind == "habit" else self.sequences.groups), key

    def put(self, v: VideoConsolidation | VideoRows | None, video: str) -> None:
        """Replace `video`'s records with `v`'s (None: the video is gone)."""
        old = self.videos.pop(video, None)
        if old is not None:
            self._apply(old, self._KINDS, -1)
        if v is not None:
            rows = v if isinstance(v, VideoRows) else self.compact(v)
            self.videos[video] = rows
            self._apply(rows, self._KINDS, +1)

    def put_sequences(self, sequences: list[ActionSequence], video: str) -> None:
        """Replace `video`'s action sequences (its other records stay)."""
        rows = self.videos[video]
        self._apply(rows, ("sequence",), -1)
        strings = {x: i for i, x in enumerate(rows.strings)}
        rows.sequence = self._rows("sequence", video, sequences, lambda a: tuple(a.steps), strings)
        rows.strings = list(strings)
        self._apply(rows, ("sequence",), +1)

    def _apply(self, rows: VideoRows, kinds, sign: int) -> None:
        video = rows.video
        for kind in kinds:
            part: _Rows = getattr(rows, kind)
            names = self.keys[kind]
            touched: dict[int, int] = {}
            for i, (k, count, seen) in enumerate(zip(part.keys.tolist(), part.counts.tolist(), part.seen.tolist())):
                table, sub = self._table(kind, names[k], sign > 0)
                g = table.get(sub)
                if g is None:
                    g = table[sub] = _SequenceGroup(None)
                g.count += sign * count
                n = g.videos.get(video, 0) + sign * seen
                if n:
                    g.videos[video] = n
                else:
                    g.videos.pop(video, None)
                touched.setdefault(k, i)
            for k, i in touched.items():
                key = names[k]
                table, sub = self._table(kind, key, False)
                g = table[sub]
                if not g.videos:
                    del table[sub]
                    if kind == "storage" and not table:
                        del self.storage.groups[key[:2]]
                    continue
                first_video = min(g.videos)
                if first_video == video and sign > 0:
                    g.first = self._thin(kind, part, i)
                elif first_video >= video:  # the first record (in video order) is another video's now
                    other = getattr(self.videos[first_video], kind)
                    g.first = self._thin(kind, other, other.rows_of(k)[0])
            if kind == "habit":
                self._triggers(part, video, sign)

    def _triggers(self, part: _Rows, video: str, sign: int) -> None:
        names = self.keys["habit"]
        triggers = [names[k][0] for k in part.keys.tolist()]
        for trigger, n in zip(triggers, part.extra.tolist()):
            per = self.triggers.setdefault(trigger, {})
            if sign > 0:
                per[video] = n
            else:
                per.pop(video, None)
        for trigger in set(triggers):
            per = self.triggers[trigger]
            if per:
                self.habits.trigger_total[trigger] = sum(per.values())
            else:
                del self.triggers[trigger]
                self.habits.trigger_total.pop(trigger, None)

    def consolidation(self, participant: str) -> Consolidation:
        rules = self.rules
        videos = sorted(self.videos)
        workflows = _WorkflowFold()  # a handful per video, and their ties are broken by first appearance: refolded
        for video in videos:
            for w in self.videos[video].workflows:
                workflows.add(w)
        kept_storage, kept_habits = rules._choose_storage(self.storage), rules._choose_habits(self.habits)
        kept_workflows, chosen = rules._choose_workflows(workflows), rules._choose_sequences(self.sequences)
        ev_workflows = {key: _Evidence() for key, _ in kept_workflows}
        _gather(ev_workflows, [w for video in videos for w in self.videos[video].workflows], _WorkflowFold.key)
        sequences = []
        for steps in chosen:
            ev = _SequenceEvidence()
            for lists in self._records_of("sequence", steps):
                ev.extend(*lists)
            sequences.append(rules._merged_sequence(steps, self.sequences.groups[steps], ev))
        return Consolidation(
            participant=participant, videos=videos,
            storage_preferences=_with_evidence(StoragePreference, kept_storage, self._evidence("storage", kept_storage)),
            organizational_habits=_with_evidence(OrganizationalHabit, kept_habits, self._evidence("habit", kept_habits)),
            workflow_patterns=_with_evidence(WorkflowPattern, kept_workflows, ev_workflows),
            action_sequences=sequences)

    def _records_of(self, kind: str, key: tuple):
        """The evidence lists of `key`'s records, in video and record order."""
        k = self.key_ids[kind][key]
        table, sub = self._table(kind, key, False)
        for video in sorted(table[sub].videos):
            rows = self.videos[video]
            part = getattr(rows, kind)
            for i in part.rows_of(k):
                yield part.lists(i, rows.strings)

    def _evidence(self, kind: str, kept) -> dict:
        out = {}
        for key, _ in kept:
            ev = out[key] = _Evidence()
            for episodes, entities in self._records_of(kind, key):
                ev.episodes.update(dict.fromkeys(episodes))
                ev.entities.update(dict.fromkeys(entities))
        return out


def _tuples(x):
    """A JSON list read back as the nested tuples it was written from."""
    return tuple(_tuples(y) for y in x) if isinstance(x, list) else x


class _SequenceGroup:
    """One step sequence across videos: its first occurrence (title, actions), count and videos."""

    __slots__ = ("first", "count", "videos", "extra")

    def __init__(self, first):
        self.first, self.count, self.videos, self.extra = first, 0, Counter(), None


class _SequenceFold:
    """Action sequences folded by their steps, without their evidence lists."""

    def __init__(self):
        self.groups: dict[tuple[str, ...], _SequenceGroup] = {}

    def add(self, a: ActionSequence) -> None:
        key = tuple(a.steps)
        g = self.groups.get(key)
        if g is None:
            g = self.groups[key] = _SequenceGroup(self._first(a))
        g.count += a.count
        g.videos.update(a.videos)

    @staticmethod
    def _first(a: ActionSequence) -> ActionSequence:
        # every field given: a field left to its default_factory costs model_construct an
        # inspect.signature call (pydantic 2.10+), which was 40% of a batch consolidation
        return ActionSequence.model_construct(
            title=a.title, steps=a.steps, actions=a.actions, activity_type=a.activity_type,
            key_objects=a.key_objects, count=0, confidence=0.0, supporting_episodes=[], segments=[], entities=[],
            videos={})


class _SequenceEvidence:
    """The ordered, duplicate-free union of a sequence's evidence over its occurrences."""

    __slots__ = ("episodes", "segments", "entities", "videos", "window")

    def __init__(self):
        self.episodes, self.segments, self.entities = {}, {}, {}
        self.videos: Counter[str] = Counter()  # (the streaming merge's) count per video
        self.window = None  # (the streaming merge's) first window seen

    def add(self, a: ActionSequence) -> None:
        self.extend(a.supporting_episodes, a.segments, a.entities)

    def extend(self, episodes, segments, entities) -> None:
        self.episodes.update(dict.fromkeys(episodes))
        self.segments.update(dict.fromkeys(segments))
        self.entities.update(dict.fromkeys(entities))


class _Fold:
    """Per-video records of one kind folded by their merge key: the first record (fields the merge
    takes from it), the summed count and the videos; without the evidence lists."""

    __slots__ = ("groups",)

    def __init__(self):
        self.groups: dict = {}

    @staticmethod
    def _thin(record):
        return record.model_copy(update={"supporting_episodes": [], "entities": [], "videos": {}})

    def _group(self, table: dict, key, record) -> _SequenceGroup:
        g = table.get(key)
        if g is None:
            g = table[key] = _SequenceGroup(self._thin(record))
        g.count += record.count
        g.videos.update(record.videos)
        return g


class _StorageFold(_Fold):
    """Storage preferences by (object, context), then by preferred location."""

    @staticmethod
    def key(p: StoragePreference) -> tuple:
        return (p.object, p.context, p.preferred_location)

    def add(self, p: StoragePreference) -> None:
        self._group(self.groups.setdefault((p.object, p.context), {}), p.preferred_location, p)


class _HabitFold(_Fold):
    """Habits by (trigger, next action), and each trigger's count (once per video)."""

    __slots__ = ("trigger_total", "_seen")

    def __init__(self):
        super().__init__()
        self.trigger_total: Counter[str] = Counter()
        self._seen: set[tuple[str, str]] = set()

    @staticmethod
    def key(h: OrganizationalHabit) -> tuple:
        return (h.trigger, h.next_action)

    def add(self, h: OrganizationalHabit) -> None:
        self._group(self.groups, (h.trigger, h.next_action), h)
        video = next(iter(h.videos))
        if (h.trigger, video) not in self._seen:  # trigger_count is per video, once per trigger
            self._seen.add((h.trigger, video))
            self.trigger_total[h.trigger] += h.trigger_count


class _WorkflowFold(_Fold):
    """Workflow patterns by (category, use, then), with the objects they moved (in first-seen order)."""

    @staticmethod
    def key(w: WorkflowPattern) -> tuple:
        return (w.category, w.use, w.then)

    def add(self, w: WorkflowPattern) -> None:
        g = self._group(self.groups, (w.category, w.use, w.then), w)
        if g.extra is None:
            g.extra = {}
        g.extra.update(dict.fromkeys(w.objects))


class _Evidence:
    """The ordered, duplicate-free union of a kept record's segments and entities."""

    __slots__ = ("episodes", "entities")

    def __init__(self):
        self.episodes, self.entities = {}, {}


def _gather(evidence: dict[tuple, _Evidence], records, key) -> None:
    """Add the evidence of `records` (in order) to the kept keys' evidence."""
    for r in records:
        ev = evidence.get(key(r))
        if ev is not None:
            ev.episodes.update(dict.fromkeys(r.supporting_episodes))
            ev.entities.update(dict.fromkeys(r.entities))


def _with_evidence(model, kept: list[tuple[tuple, dict]], evidence: dict) -> list:
    return [model(**fields, supporting_episodes=list(evidence[key].episodes), entities=list(evidence[key].entities))
            for key, fields in kept]


def _longest_cover(videos: dict[tuple[str, ...], int]) -> dict[tuple[str, ...], int]:
    """For every step sequence that is a contiguous part of a longer candidate: the most videos any
    such longer candidate is seen in. Each candidate lists its own parts (a few steps: a handful
    of parts), where comparing every pair of candidates grew with their square (minutes at 100
    hours of video, where every sequence recurs in dozens of videos)."""
    cover: dict[tuple[str, ...], int] = {}
    for steps, n_videos in videos.items():
        for n in range(1, len(steps)):
            for i in range(len(steps) - n + 1):
                part = steps[i:i + n]
                if cover.get(part, -1) < n_videos:
                    cover[part] = n_videos
    return cover


def _longest_cover_pairwise(videos: dict[tuple[str, ...], int]) -> dict[tuple[str, ...], int]:
    """`_longest_cover` by comparing every pair, as first written (the tests' reference)."""
    out = {}
    for steps in videos:
        n = len(steps)
        longer = [s for s in videos if len(s) > n and any(s[i:i + n] == steps for i in range(len(s) - n + 1))]
        if longer:
            out[steps] = max(videos[s] for s in longer)
    return out


_lcs = lcs_length


class EpisodeSummary:
    """One episode as the routine-skill merge reads it: its goal, step tokens, canonical steps
    (text and action, immediate repeats collapsed), the object kinds and entities it touched."""

    __slots__ = ("video", "goal", "head", "cat", "tokens", "canon", "kinds", "entities", "t_start", "t_end", "segments")

    def __init__(self, video, goal, head, cat, tokens, canon, kinds, entities, t_start, t_end, segments):
        self.video, self.goal, self.head, self.cat, self.tokens, self.canon = video, goal, head, cat, tokens, canon
        self.kinds, self.entities, self.t_start, self.t_end, self.segments = kinds, entities, t_start, t_end, segments


class ToolUse:
    """A narrated step done with an instrument: (verb, target kind, tool kind) and its evidence."""

    __slots__ = ("verb", "target", "tool", "video", "segment", "narration", "objects")

    def __init__(self, verb, target, tool, video, segment, narration, objects):
        self.verb, self.target, self.tool, self.video = verb, target, tool, video
        self.segment, self.narration, self.objects = segment, narration, objects


class RuleEnricher:
    """Inferred-knowledge enrichment: routine skills from episodes, tool preferences from narrations."""

    name = "deterministic"
    min_episodes = 2  # a routine is a goal reached at least twice; repetition across videos raises confidence
    hard_gap = 30.0  # seconds of no action that always end an episode
    soft_gap = 10.0  # a shorter pause ends one when the kind of work changes
    min_steps, max_steps, chunk = 3, 15, 12
    max_canonical_steps = 12
    key_object_share = 0.4
    tool_min_count = 2
    caps = {"routine": 30, "preference": 20}

    def enrich(self, memory: ParticipantMemory, consolidation: Consolidation) -> Enrichment:
        return Enrichment(participant=memory.participant, routine_skills=self.routine_skills(memory),
                          generated_preferences=self.tool_preferences(memory))

    # -- routine skills ----------------------------------------------------------------
    def episodes(self, steps: list[MemoryStep]) -> list[list[MemoryStep]]:
        out: list[list[MemoryStep]] = []
        cur: list[MemoryStep] = []
        cur_cat = None
        for s in steps:
            cat = vocab.category(s.verb)
            if cur:
                gap = s.t - cur[-1].t
                if gap > self.hard_gap or (gap > self.soft_gap and cat and cur_cat and cat != cur_cat):
                    out.append(cur)
                    cur, cur_cat = [], None
            cur.append(s)
            cur_cat = cat or cur_cat
        if cur:
            out.append(cur)
        chunks = []
        for ep in out:
            if len(ep) > self.max_steps:
                k = math.ceil(len(ep) / self.chunk)
                size = math.ceil(len(ep) / k)
                chunks += [ep[i:i + size] for i in range(0, len(ep), size)]
            else:
                chunks.append(ep)
        return [c for c in chunks if len(c) >= self.min_steps]

    @staticmethod
    def goal(ep: list[MemoryStep]) -> tuple[str, str, str | None]:
        """(goal text, head object kind, verb category) of an episode."""
        work = [s for s in ep if not s.is_filler]
        pool = work or ep
        verbs = Counter(s.verb for s in pool)
        top = max(verbs, key=lambda v: (verbs[v], -next(i for i, s in enumerate(pool) if s.verb == v)))
        objs = Counter(s.main.kind for s in pool if s.verb == top and not s.main.is_fixture) or \
            Counter(s.main.kind for s in pool if not s.main.is_fixture) or Counter(s.main.kind for s in pool)
        head = max(objs, key=lambda k: (objs[k], -next(i for i, s in enumerate(pool) if s.main.kind == k)))
        if work:
            return f"{vocab.phrase(top)} {display(head)}", head, vocab.category(top)
        if top in vocab.RELEASING or top == "insert":
            return f"put away {display(head)}", head, "setup"
        if top in vocab.TAKING:
            return f"get {display(head)}", head, "setup"
        return f"{vocab.phrase(top)} {display(head)}", head, "setup"

    def video_episodes(self, steps: list[MemoryStep], shared: dict | None = None) -> list[EpisodeSummary]:
        """One video's episodes as much as `routine_skills_from` reads of them (the merge across
        videos needs no step). `shared`, if given, keeps one (text, action) per distinct
        canonical step across calls (every episode of a participant is held until the merge)."""
        out = []
        for ep in self.episodes(steps):
            goal, head, cat = self.goal(ep)
            canon, last = [], None
            for s in ep:
                if s.token != last:
                    if shared is None:
                        canon.append((s.text(), s.action()))
                    else:
                        key = (s.text(), s.verb, s.main.kind, s.where()[0])
                        step = shared.get(key)
                        if step is None:
                            step = shared[key] = (key[0], s.action())
                        canon.append(step)
                    last = s.token
            entities: dict[tuple[str, str], int] = {}
            for s in ep:
                for o in s.objects:
                    entities[(o.kind, o.entity)] = entities.get((o.kind, o.entity), 0) + 1
            out.append(EpisodeSummary(
                video=ep[0].video, goal=goal, head=head, cat=cat, tokens=tuple(s.token for s in ep), canon=canon,
                kinds=sorted({o.kind for s in ep for o in s.objects}), entities=list(entities.items()),
                t_start=round(ep[0].t, 2), t_end=round(ep[-1].t, 2), segments=_uniq(s.segment for s in ep)))
        return out

    def routine_skills(self, memory: ParticipantMemory) -> list[RoutineSkill]:
        by_video = memory.steps_by_video()  # a video's steps read one at a time (a table makes them when read)
        shared: dict = {}
        return self.routine_skills_from(ep for video in sorted(by_video) for ep in self.video_episodes(by_video[video], shared))

    def routine_skills_from(self, summaries) -> list[RoutineSkill]:
        """Routine skills from every video's episodes (`video_episodes`), in video order."""
        groups: dict[str, list[EpisodeSummary]] = defaultdict(list)
        for ep in summaries:
            groups[ep.goal].append(ep)
        out = []
        for goal, eps in groups.items():
            if len(eps) < self.min_episodes:
                continue
            out.append(self.routine_of(goal, eps))
        return self.ranked_routines(out)

    def ranked_routines(self, routines) -> list[RoutineSkill]:
        """The routine skills kept: cross-video routines first, at most `caps['routine']`."""
        return sorted(routines, key=lambda r: (-len(r.videos), -r.count, r.goal))[: self.caps["routine"]]

    def routine_of(self, goal: str, eps: list[EpisodeSummary]) -> RoutineSkill:
        """The routine skill of one goal's episodes (in video order)."""
        videos = Counter(ep.video for ep in eps)
        seqs = [ep.tokens for ep in eps]
        sample = list(range(len(eps)))[:: max(1, len(eps) // 40)][:40]  # bound the O(n^2) medoid search
        sims = {i: [(2 * _lcs(seqs[i], seqs[j]) / (len(seqs[i]) + len(seqs[j]))) for j in sample if j != i] for i in sample}
        medoid = max(sample, key=lambda i: (sum(sims[i]) / max(len(sims[i]), 1), -i))
        cohesion = sum(sims[medoid]) / max(len(sims[medoid]), 1)
        steps = [text for text, _ in eps[medoid].canon]
        actions = [action for _, action in eps[medoid].canon]
        head = eps[0].head
        kinds: Counter[str] = Counter()
        entity_of: dict[str, Counter[str]] = defaultdict(Counter)
        for ep in eps:
            for k in ep.kinds:
                kinds[k] += 1
            for (k, e), n in ep.entities:
                entity_of[k][e] += n
        key_objects = [head] + [k for k, n in sorted(kinds.items(), key=lambda kv: (-kv[1], kv[0]))
                                if k != head and n / len(eps) >= self.key_object_share]
        key_objects = key_objects[:8]
        cats = Counter(ep.cat for ep in eps)
        episodes = [Episode(video=ep.video, t_start=ep.t_start, t_end=ep.t_end, segments=ep.segments) for ep in eps]
        return RoutineSkill(
            goal=goal, activity_type=vocab.ACTIVITY_TYPE[cats.most_common(1)[0][0]],
            canonical_steps=steps[: self.max_canonical_steps], actions=actions[: self.max_canonical_steps],
            key_objects=[display(k) for k in key_objects],
            supporting_episodes=[e.segments[0] for e in episodes], segments=_uniq(s for e in episodes for s in e.segments),
            episodes=episodes, count=len(eps), confidence=_conf(_support(len(videos)) * (0.5 + 0.5 * cohesion)),
            entities=[entity_of[k].most_common(1)[0][0] for k in key_objects], videos=dict(sorted(videos.items())),
        )

    # -- generated preferences ---------------------------------------------------------
    def tool_uses(self, steps: list[MemoryStep]) -> list[ToolUse]:
        """The steps done with an instrument ("stir egg using spatula"), as `tool_preferences_from` reads them."""
        out = []
        for s in steps:
            if s.is_filler or s.main.category in vocab.TOOL_CATEGORIES:
                continue
            tools = [o for o in s.objects[1:] if o.category in vocab.TOOL_CATEGORIES and not o.is_fixture]
            for tool in tools[:1]:
                out.append(ToolUse(s.verb, s.main.kind, tool.kind, s.video, s.segment, s.narration, s.objects))
        return out

    def tool_preferences(self, memory: ParticipantMemory) -> list[GeneratedPreference]:
        return self.tool_preferences_from(u for s in memory.iter_steps() for u in self.tool_uses([s]))

    def tool_preferences_from(self, tool_uses) -> list[GeneratedPreference]:
        """Generated preferences from every video's tool uses (`tool_uses`), in video and time order."""
        uses: dict[tuple[str, str], dict[str, list[ToolUse]]] = defaultdict(lambda: defaultdict(list))
        for u in tool_uses:
            uses[(u.verb, u.target)][u.tool].append(u)
        out = []
        by_verb: dict[str, dict[str, list[tuple[str, list[ToolUse]]]]] = defaultdict(lambda: defaultdict(list))
        for (verb, target), tools in uses.items():
            counts = {t: len(ss) for t, ss in tools.items()}
            best = min(counts, key=lambda t: (-counts[t], t))
            by_verb[verb][best].append((target, tools[best]))
            if counts[best] < self.tool_min_count:
                continue
            out.append(self._tool_pref(verb, [target], best, tools[best], {t: n for t, n in counts.items() if t != best}))
        for verb, tools in by_verb.items():  # the same instrument across several targets of one action
            for tool, targets in tools.items():
                if len(targets) < 2 or sum(len(ss) for _, ss in targets) < 3:
                    continue
                steps = [s for _, ss in targets for s in ss]
                out.append(self._tool_pref(verb, [t for t, _ in sorted(targets, key=lambda x: -len(x[1]))], tool, steps, {}))
        out.sort(key=lambda p: (-p.count, p.preference))
        return out[: self.caps["preference"]]

    @staticmethod
    def _tool_pref(verb: str, targets: list[str], tool: str, steps: list[ToolUse], alternatives: dict[str, int]) -> GeneratedPreference:
        names = [display(t) for t in targets]
        what = names[0] if len(names) == 1 else ", ".join(names[:-1][:3]) + f" or {names[-1]}"
        statement = f"Usually uses the {display(tool)} to {vocab.phrase(verb)} the {what}"
        if alternatives:
            statement += " (rather than the " + " or ".join(display(a) for a in sorted(alternatives)) + ")"
        videos = Counter(s.video for s in steps)
        segments = _uniq(s.segment for s in steps)
        share = len(steps) / (len(steps) + sum(alternatives.values()))
        keywords = _uniq([display(tool), vocab.phrase(verb), *vocab.SYNONYMS.get(verb, ()), *names])
        example = steps[0]
        return GeneratedPreference(
            subtype="tool", preference=statement, keywords=keywords, objects=_uniq([display(tool), *names]),
            context=f"{vocab.phrase(verb)} {what}", count=len(steps),
            confidence=_conf(share * _support(len(segments))),
            evidence_summary=f"{len(steps)} narrated actions in {len(videos)} video(s), e.g. \"{example.narration}\" ({example.segment})",
            supporting_evidence_ids=segments, entities=_uniq(o.entity for s in steps for o in s.objects if o.kind in (tool, *targets)),
            alternatives=alternatives, videos=dict(sorted(videos.items())),
            actions=[StepAction(verb=verb, noun=t, instrument=tool) for t in targets],
        )
