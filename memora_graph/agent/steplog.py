"""The typed reader's activity log over the columns kept with the tool stores (retrieve/steps.py).

`StepLog` is the sequence of `LogStep`s that agent/open_answer.py answers from, in (video, time)
order, without a `LogStep` object per step: a step's classes (verb, objects, nouns, place) are a
function of its wording alone, computed once per distinct wording, and the reader's filters are
evaluated once per wording and applied to every step with one array lookup (`where`). Runs
(consecutive steps of one video with the same action) are found with array comparisons. A step
becomes a `LogStep` only when an answer reads it.
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


class Steps(Sequence):
    """Some steps of a log, in log order (positions into it), read as `LogStep`s on demand."""

    def __init__(self, log: StepLog, at: np.ndarray):
        self.log, self.at = log, at

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


class StepLog(Sequence):
    """Every narrated step in the person's memory as classes, in (video, time) order."""

    def __init__(self, rows: StepRows, classes: list[Classes], grown_from: StepLog | None = None):
        """`grown_from`: a log of the same participant whose wordings are the first of these
        (the log before a remember): what was derived per wording is reused."""
        self.rows, self.classes = rows, classes
        old = grown_from._protos if grown_from is not None else []
        self._protos = old + [LogStep("", 0.0, "", *c, w[3]) for c, w in
                              zip(classes[len(old):], rows.words[len(old):])]

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

    # -- what the reader asks ------------------------------------------------------------------
    def word_mask(self, pred: Callable[[LogStep], bool]) -> np.ndarray:
        """`pred` of each distinct wording (a step with its classes and text, no video or time)."""
        return np.fromiter((bool(pred(s)) for s in self._protos), dtype=bool, count=len(self._protos))

    def where(self, pred: Callable[[LogStep], bool]) -> Steps:
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
            used = np.zeros(len(self.classes), dtype=bool)
            used[np.unique(self.rows.word)] = True
            got = self._nouns = {n for w in np.flatnonzero(used) for n in self.classes[w][2]}
            self._verbs = {self.classes[w][0] for w in np.flatnonzero(used) if self.classes[w][0]}
        return got

    @property
    def verbs(self) -> set[str]:
        _ = self.nouns
        return self._verbs

    # -- actions: (verb, first object) -----------------------------------------------------
    def _pairs(self) -> tuple[list[tuple], np.ndarray]:
        """The distinct (verb, first object or "") of the wordings, and each wording's index."""
        got = self.__dict__.get("_pair_of_word")
        if got is None:
            ids: dict = {}
            of = np.asarray([ids.setdefault((c[0], c[1][0] if c[1] else ""), len(ids)) for c in self.classes],
                            dtype=np.int64)
            got = self._pair_of_word = (list(ids), of)
        return got

    def pair_ids(self, at: np.ndarray) -> np.ndarray:
        """The action (index into `_pairs()[0]`) of the steps at positions `at`."""
        return self._pairs()[1][self.rows.word[at]]

    def action_counts(self, steps: Steps) -> Counter:
        """Counter of (verb, first object or "") over `steps`, keys in order of first occurrence
        (as counting them one by one makes it: `most_common` breaks ties by that order)."""
        pairs = self._pairs()[0]
        ids = self.pair_ids(steps.at)
        out: Counter = Counter()
        if not len(ids):
            return out
        uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
        for k in np.argsort(first, kind="stable"):
            out[pairs[int(uniq[k])]] += int(counts[k])
        return out

    # -- runs: consecutive steps of one video with the same action, one event -----------------
    def _run_keys(self) -> np.ndarray:
        got = self.__dict__.get("_action_of_word")
        if got is None:
            ids: dict = {}
            got = self._action_of_word = np.asarray(
                [ids.setdefault((c[0], c[1][:1]), len(ids)) for c in self.classes], dtype=np.int64)
        return got

    @property
    def run_starts(self) -> np.ndarray:
        """The position of each run's first step, in log order."""
        got = self.__dict__.get("_run_starts")
        if got is None:
            r = self.rows
            if not len(r):
                got = np.zeros(0, dtype=np.int64)
            else:
                act = self._run_keys()[r.word]
                change = (r.video[1:] != r.video[:-1]) | (act[1:] != act[:-1])
                got = np.flatnonzero(np.r_[True, change])
            self._run_starts = got
        return got

    def runs_where(self, pred: Callable[[LogStep], bool]) -> np.ndarray:
        """Indexes (into `run_starts`) of the runs whose first step `pred` holds for."""
        starts = self.run_starts
        return np.flatnonzero(self.word_mask(pred)[self.rows.word[starts]])

    def runs_followed(self, pred: Callable[[LogStep], bool]) -> np.ndarray:
        """The first step (position) of each run that follows, in the same video, a run whose
        first step `pred` holds for; in log order."""
        starts = self.run_starts
        idx = self.runs_where(pred)
        idx = idx[idx + 1 < len(starts)]
        a, b = starts[idx], starts[idx + 1]
        return b[self.rows.video[a] == self.rows.video[b]]

    def run_windows(self, pred: Callable[[LogStep], bool], before: int, after: int) -> list[tuple]:
        """For each run whose first step `pred` holds for (in log order), the actions (verb,
        first object or "") of the first steps of the runs from `before` runs before it to `after`
        after it that are in its video, as a tuple."""
        starts = self.run_starts
        idx = self.runs_where(pred)
        if not len(idx):
            return []
        pairs = self._pairs()[0]
        video = self.rows.video
        own = video[starts[idx]]
        cols = []
        for o in range(-before, after + 1):
            j = idx + o
            ok = (j >= 0) & (j < len(starts))
            pos = starts[np.clip(j, 0, len(starts) - 1)]
            ok &= video[pos] == own
            cols.append(np.where(ok, self.pair_ids(pos), -1))
        return [tuple(pairs[k] for k in row if k >= 0) for row in zip(*(c.tolist() for c in cols))]
