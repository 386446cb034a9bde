"""The typed query's activity log over the columns kept with the tool stores (retrieve/steps.py).

`StepLog` is the sequence of `LogStep`s that `query.answer` answers from, in (video, time) order,
without a `LogStep` object per step: a step's classes (verb, objects, nouns, place) are a function
of its wording alone, computed once per distinct wording, and a filter is evaluated once per
wording and applied to every step with one array lookup (`where`). `Steps` is a part of the log
(a query's scope, the steps a filter kept), as positions into it, in the order the answer reads
them; the same operations apply to it. Runs (consecutive steps of one video with the same action)
are found with array comparisons. A step becomes a `LogStep` only when an answer reads it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from memora_graph.retrieve.steps import StepRows


@dataclass(frozen=True)
class LogStep:
    video: str
    t: float
    segment: str
    verb: str | None
    objects: tuple[str, ...]  # the step's own object classes
    nouns: tuple[str, ...]  # every class the narration names
    place: str | None  # where it went / came from
    text: str


Classes = tuple  # (verb, objects, nouns, place)
Pred = Callable[[LogStep], bool]


def first_order_counts(keys: np.ndarray) -> list[tuple[int, int]]:
    """(key, count) of an integer array, keys in order of first occurrence (as counting one by one
    makes a Counter: `most_common` breaks ties by that order)."""
    if not len(keys):
        return []
    uniq, first, counts = np.unique(keys, return_index=True, return_counts=True)
    return [(int(uniq[k]), int(counts[k])) for k in np.argsort(first, kind="stable")]


def _pair_key(c: Classes) -> tuple:
    """A wording's action: (verb, first object or "")."""
    return c[0], c[1][0] if c[1] else ""


def _run_key(c: Classes) -> tuple:
    """A wording's action as a run reads it: (verb, first object)."""
    return c[0], c[1][:1]


class Steps(Sequence):
    """Some steps of a log (positions into it), in the order an answer reads them (log order but
    for a scope ordered by closeness to a moment), read as `LogStep`s on demand."""

    def __init__(self, log: StepLog, at: np.ndarray, whole: bool = False):
        """`whole`: `at` is every position of the log in order (its columns are the log's own)."""
        self.log, self.at, self.whole = log, np.asarray(at, dtype=np.int64), whole

    def __len__(self) -> int:
        return len(self.at)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return Steps(self.log, self.at[i])
        return self.log.step(int(self.at[i]))

    def __iter__(self) -> Iterator[LogStep]:
        step = self.log.step
        return (step(int(p)) for p in self.at)

    def __bool__(self) -> bool:
        return len(self.at) > 0

    # -- columns of these steps --------------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        return self.log.rows.t if self.whole else self.log.rows.t[self.at]

    @property
    def video_ix(self) -> np.ndarray:
        return self.log.rows.video if self.whole else self.log.rows.video[self.at]

    @property
    def word(self) -> np.ndarray:
        return self.log.rows.word if self.whole else self.log.rows.word[self.at]

    def mask(self, pred: Pred) -> np.ndarray:
        """`pred` of each of these steps (evaluated once per wording)."""
        return self.log.word_mask(pred)[self.word]

    def where(self, pred: Pred) -> Steps:
        """The steps for which `pred` holds, in this order; `pred` reads only a step's classes and text."""
        return Steps(self.log, self.at[self.mask(pred)])

    def keep(self, mask: np.ndarray) -> Steps:
        return Steps(self.log, self.at[mask])

    def videos(self) -> list[str]:
        """The distinct videos of these steps, in order."""
        rows = self.log.rows
        v = rows.video[self.at]
        first = np.flatnonzero(np.r_[True, v[1:] != v[:-1]]) if len(v) else v
        return list(dict.fromkeys(rows.videos[int(x)] for x in v[first]))

    def segment_ids(self, limit: int) -> list[str]:
        """The distinct segments of these steps, in order, at most `limit`."""
        rows, out, seen = self.log.rows, [], set()
        for p in self.at:
            s = int(rows.segment[p])
            if s not in seen:
                seen.add(s)
                out.append(rows.segments[s])
                if len(out) == limit:
                    break
        return out

    def count_by(self, key: Callable[[LogStep], object]) -> Counter:
        """Counter of `key` (a function of a step's wording) over these steps, keys in order of
        first occurrence, as counting them one by one makes it."""
        protos, out = self.log.protos, Counter()
        for w, n in first_order_counts(self.word):
            out[key(protos[w])] += n
        return out

    def action_counts(self) -> Counter:
        """Counter of (verb, first object or "") over these steps, in order of first occurrence."""
        return self.log.action_counts(self)

    # -- runs: consecutive steps of one video with the same action, one event -----------------
    def run_starts(self) -> np.ndarray:
        """The index (into these steps) of each run's first step."""
        got = self.__dict__.get("_run_starts")
        if got is None:
            if not len(self.at):
                got = np.zeros(0, dtype=np.int64)
            else:
                v = self.video_ix
                act = self.log.run_keys()[self.word]
                got = np.flatnonzero(np.r_[True, (v[1:] != v[:-1]) | (act[1:] != act[:-1])])
            self._run_starts = got
        return got

    def run_ends(self) -> np.ndarray:
        """The index (into these steps) of each run's last step."""
        starts = self.run_starts()
        return np.r_[starts[1:] - 1, len(self.at) - 1] if len(starts) else starts

    def run_firsts(self) -> np.ndarray:
        """The log position of each run's first step."""
        return self.run_starts() if self.whole else self.at[self.run_starts()]

    def runs_where(self, pred: Pred) -> np.ndarray:
        """Indexes (into `run_starts`) of the runs whose first step `pred` holds for."""
        return np.flatnonzero(self.log.word_mask(pred)[self.log.rows.word[self.run_firsts()]])

    def run_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """(first step of a run, first step of the next run) as log positions, for each two runs
        that follow each other in one video, in order (found once per `Steps`)."""
        got = self.__dict__.get("_run_pairs")
        if got is None:
            firsts = self.run_firsts()
            a, b = firsts[:-1], firsts[1:]
            same = self.log.rows.video[a] == self.log.rows.video[b]
            got = self._run_pairs = (a[same], b[same])
        return got

    def runs_followed(self, pred: Pred) -> np.ndarray:
        """The first step (log position) of each run that follows, in the same video, a run whose
        first step `pred` holds for; in order."""
        firsts = self.run_firsts()
        idx = self.runs_where(pred)
        idx = idx[idx + 1 < len(firsts)]
        a, b = firsts[idx], firsts[idx + 1]
        return b[self.log.rows.video[a] == self.log.rows.video[b]]

    def run_windows(self, pred: Pred, before: int, after: int) -> list[tuple]:
        """For each run whose first step `pred` holds for (in order), the actions (verb, first
        object or "") of the first steps of the runs from `before` runs before it to `after` after
        it that are in its video, as a tuple."""
        firsts = self.run_firsts()
        idx = self.runs_where(pred)
        if not len(idx):
            return []
        pairs = self.log.pairs()[0]
        video = self.log.rows.video
        own = video[firsts[idx]]
        cols = []
        for o in range(-before, after + 1):
            j = idx + o
            ok = (j >= 0) & (j < len(firsts))
            pos = firsts[np.clip(j, 0, len(firsts) - 1)]
            ok &= video[pos] == own
            cols.append(np.where(ok, self.log.pair_ids(pos), -1))
        return [tuple(pairs[k] for k in row if k >= 0) for row in zip(*(c.tolist() for c in cols))]


class StepLog(Sequence):
    """Every narrated step in the person's memory as classes, in (video, time) order."""

    def __init__(self, rows: StepRows, classes: list[Classes], grown_from: StepLog | None = None):
        """`grown_from`: a log of the same participant whose wordings are the first of these
        (the log before a remember): what was derived per wording is reused."""
        self.rows, self.classes = rows, classes
        old = grown_from.protos if grown_from is not None else []
        self.protos = old + [LogStep("", 0.0, "", *c, w[3]) for c, w in
                             zip(classes[len(old):], rows.words[len(old):])]
        if grown_from is not None:
            self._grow(grown_from)

    def _grow(self, old: StepLog) -> None:
        """Derive what `old` (the log these rows grew from by `StepRows.added`) has derived: per
        wording extended by the new wordings, the runs of the whole log mended where steps went in,
        so a remember costs the next `ask` its own steps, not a pass over the whole log."""
        n = len(old.classes)
        if "_nouns" in old.__dict__:  # every wording of the rows is used by a step, and steps are only added
            new = self.classes[n:]
            self._nouns = old._nouns | {x for c in new for x in c[2]}
            self._verbs = old._verbs | {c[0] for c in new if c[0]}
        for cache, key in (("_pair_of_word", _pair_key), ("_action_of_word", _run_key)):
            got = old.__dict__.get(cache)
            if got is not None:
                ids = dict(got[0])
                tail = [ids.setdefault(key(c), len(ids)) for c in self.classes[n:]]
                self.__dict__[cache] = (ids, np.concatenate([got[1], np.asarray(tail, dtype=np.int64)]))
        parent, at = self.rows.grown or (None, None)
        runs = old._all.__dict__.get("_run_starts") if "_all" in old.__dict__ else None
        if runs is None or parent is None or parent() is not old.rows:  # (runs found: `run_keys` was extended above)
            return
        new_at = at + np.arange(len(at))  # where `StepRows.added` put each new step
        size = len(self.rows)
        starts = np.zeros(size, dtype=bool)
        starts[runs + np.searchsorted(at, runs, "right")] = True  # old steps move up by the new ones before them
        near = np.unique(np.r_[new_at, new_at + 1])  # the only steps whose predecessor changed
        near = near[near < size]
        prev = np.maximum(near - 1, 0)
        act, video, word = self.run_keys(), self.rows.video, self.rows.word
        starts[near] = (near == 0) | (video[near] != video[prev]) | (act[word[near]] != act[word[prev]])
        self.all._run_starts = np.flatnonzero(starts)

    def __len__(self) -> int:
        return len(self.rows)

    def step(self, p: int) -> LogStep:
        r = self.rows
        c = self.classes[int(r.word[p])]
        return LogStep(r.videos[int(r.video[p])], float(r.t[p]), r.segments[int(r.segment[p])], *c,
                       r.words[int(r.word[p])][3])

    def __getitem__(self, i):
        if isinstance(i, slice):
            return Steps(self, np.arange(len(self))[i])
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        return self.step(i)

    def __iter__(self) -> Iterator[LogStep]:
        return (self.step(p) for p in range(len(self)))

    @property
    def all(self) -> Steps:
        """Every step, as `Steps` (its runs found once per log)."""
        got = self.__dict__.get("_all")
        if got is None:
            got = self._all = Steps(self, np.arange(len(self)), whole=True)
        return got

    # -- what the reader asks ------------------------------------------------------------------
    def word_mask(self, pred: Pred) -> np.ndarray:
        """`pred` of each distinct wording (a step with its classes and text, no video or time)."""
        return np.fromiter((bool(pred(s)) for s in self.protos), dtype=bool, count=len(self.protos))

    def where(self, pred: Pred) -> Steps:
        """The steps for which `pred` holds; `pred` reads only a step's classes and text."""
        return Steps(self, self.rows.where(self.word_mask(pred)))

    def of_video(self, video: str) -> Steps:
        lo, hi = self.rows.video_range(video)
        return Steps(self, np.arange(lo, hi))

    def of_segments(self, ids) -> Steps:
        return Steps(self, self.rows.of_segments(ids))

    @property
    def nouns(self) -> set[str]:
        got = self.__dict__.get("_nouns")
        if got is None:
            used = np.bincount(self.rows.word, minlength=len(self.classes)) > 0
            got = self._nouns = {n for w in np.flatnonzero(used) for n in self.classes[w][2]}
            self._verbs = {self.classes[w][0] for w in np.flatnonzero(used) if self.classes[w][0]}
        return got

    @property
    def verbs(self) -> set[str]:
        _ = self.nouns
        return self._verbs

    # -- actions: (verb, first object) -----------------------------------------------------
    def pairs(self) -> tuple[list[tuple], np.ndarray]:
        """The distinct (verb, first object or "") of the wordings, and each wording's index."""
        got = self.__dict__.get("_pair_of_word")
        if got is None:
            ids: dict = {}
            of = np.asarray([ids.setdefault(_pair_key(c), len(ids)) for c in self.classes], dtype=np.int64)
            got = self._pair_of_word = (ids, of)
        names = self.__dict__.get("_pair_names")
        if names is None:
            names = self._pair_names = list(got[0])
        return names, got[1]

    def pair_ids(self, at: np.ndarray) -> np.ndarray:
        """The action (index into `pairs()[0]`) of the steps at positions `at`."""
        return self.pairs()[1][self.rows.word[at]]

    def action_counts(self, steps: Steps) -> Counter:
        """Counter of (verb, first object or "") over `steps`, keys in order of first occurrence."""
        pairs = self.pairs()[0]
        out: Counter = Counter()
        for k, n in first_order_counts(self.pair_ids(steps.at)):
            out[pairs[k]] += n
        return out

    def run_keys(self) -> np.ndarray:
        """Each wording's action as a run reads it: (verb, first object)."""
        got = self.__dict__.get("_action_of_word")
        if got is None:
            ids: dict = {}
            got = self._action_of_word = (ids, np.asarray([ids.setdefault(_run_key(c), len(ids)) for c in self.classes],
                                                          dtype=np.int64))
        return got[1]

    # -- runs of the whole log (tests/retrieve/test_steps.py) ---------------------------------
    @property
    def run_starts(self) -> np.ndarray:
        """The position of each run's first step, in log order."""
        return self.all.run_firsts()

    def runs_followed(self, pred: Pred) -> np.ndarray:
        return self.all.runs_followed(pred)

    def run_windows(self, pred: Pred, before: int, after: int) -> list[tuple]:
        return self.all.run_windows(pred, before, after)
