"""The activity log as columns: every narrated step of a participant's segments, in (video,
time) order, kept with the persisted tool stores so that the typed reader (`ask`,
agent/query/) never reads and parses the whole log at a call.

A step is four numbers: its video (index into the sorted video names), its time (seconds into
the video), its segment (index into the segment ids) and its wording (index into the table of
distinct `(narration, object, action, text)`: a person's narrations repeat, 1,151,204 steps in
31,977 wordings at 1,000 h). What the reader derives from a step (its EPIC classes) is a function
of its wording alone, so the reader computes it once per wording and finds the steps it wants
with one array lookup (`StepRows.where`).

The rows are those of `queries/_open_action_log.cypher` (ordered by video and turn), each
segment's `action_breakdown` steps in order, sorted stably by (video, time), as the reader's
whole read of the log sorted them. `added` puts a remembered segment's steps in their place:
after the steps of equal video and time (as `bisect.insort_right` put them), without reading
the rest again."""

from __future__ import annotations

import bisect
import json
import weakref
from collections.abc import Iterable

import numpy as np

ARRAYS = ("video", "t", "segment", "word")


def segment_steps(seg: dict) -> list[tuple[float, tuple[str, str, str, str]]]:
    """(time, wording) of each narrated step of one activity record (id, video, t_start,
    action_breakdown): a wording is (narration, object, action, text)."""
    try:
        steps = json.loads(seg["action_breakdown"] or "[]")
    except (TypeError, ValueError):
        steps = []
    t0 = float(seg["t_start"] or 0.0)
    out = []
    for s in steps:
        narration = str(s.get("narration") or "")
        obj = str(s.get("object") or "")
        action = str(s.get("action") or "")
        try:
            t = t0 + float(s.get("timestamp") or 0.0)
        except (TypeError, ValueError):
            t = t0
        out.append((t, (narration, obj, action, narration or f"{s.get('action', '')} {obj}".strip())))
    return out


class StepRows:
    """Every narrated step of one participant, as columns (see the module's doc)."""

    def __init__(self, videos: list[str], segments: list[str], words: list[tuple[str, str, str, str]],
                 video: np.ndarray, t: np.ndarray, segment: np.ndarray, word: np.ndarray):
        self.videos, self.segments, self.words = videos, segments, words
        self.video, self.t, self.segment, self.word = video, t, segment, word
        self.lineage = object()  # shared by the rows `added` grows from these (their first segments are these)
        self.grown: tuple | None = None  # set by `added`: (the rows these grew from, weakly; where the steps went)

    def __len__(self) -> int:
        return len(self.t)

    # -- building, persisting ---------------------------------------------------------------
    @classmethod
    def build(cls, rows: Iterable[dict]) -> StepRows:
        """From `_open_action_log` rows (in its order: video, turn)."""
        names, segments, words, word_ix = [], [], [], {}
        vcol, tcol, scol, wcol = [], [], [], []
        video_ix: dict[str, int] = {}
        for seg in rows:
            steps = segment_steps(seg)
            if not steps:
                continue
            v = video_ix.setdefault(seg["video"], len(video_ix))
            si = len(segments)
            segments.append(seg["id"])
            for t, w in steps:
                wi = word_ix.get(w)
                if wi is None:
                    wi = word_ix[w] = len(words)
                    words.append(w)
                vcol.append(v)
                tcol.append(t)
                scol.append(si)
                wcol.append(wi)
        names = sorted(video_ix)
        remap = np.empty(len(names), dtype=np.int32)
        for rank, name in enumerate(names):
            remap[video_ix[name]] = rank
        video = remap[np.asarray(vcol, dtype=np.int64)] if vcol else np.zeros(0, np.int32)
        t = np.asarray(tcol, dtype=np.float64)
        order = np.lexsort((t, video))  # stable: equal (video, time) keep the query's order
        return cls(names, segments, words, video[order].astype(np.int32), t[order],
                   np.asarray(scol, dtype=np.int32)[order], np.asarray(wcol, dtype=np.int32)[order])

    def arrays(self) -> tuple[dict, dict[str, np.ndarray]]:
        return ({"videos": self.videos, "segments": self.segments, "words": [list(w) for w in self.words]},
                {"video": self.video, "t": self.t, "segment": self.segment, "word": self.word})

    @classmethod
    def from_arrays(cls, header: dict, arrays: dict[str, np.ndarray]) -> StepRows:
        n = len(arrays["t"])
        if any(len(arrays[k]) != n for k in ARRAYS):
            raise ValueError("step columns of different lengths")
        return cls(list(header["videos"]), list(header["segments"]), [tuple(w) for w in header["words"]],
                   arrays["video"], arrays["t"], arrays["segment"], arrays["word"])

    # -- reading ----------------------------------------------------------------------------
    def video_range(self, name: str) -> tuple[int, int]:
        """The positions [lo, hi) of a video's steps (empty where it has none)."""
        i = bisect.bisect_left(self.videos, name)
        if i == len(self.videos) or self.videos[i] != name:
            return 0, 0
        return int(np.searchsorted(self.video, i, "left")), int(np.searchsorted(self.video, i, "right"))

    def where(self, word_mask: np.ndarray) -> np.ndarray:
        """Positions (in log order) of the steps whose wording `word_mask` selects."""
        return np.flatnonzero(np.asarray(word_mask, dtype=bool)[self.word])

    def of_segments(self, ids: Iterable[str]) -> np.ndarray:
        """Positions (in log order) of the steps of the segments `ids`."""
        index = self.__dict__.get("_segment_index")
        if index is None:
            index = self._segment_index = {s: i for i, s in enumerate(self.segments)}
        wanted = [index[i] for i in ids if i in index]
        if not wanted:
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(np.isin(self.segment, np.asarray(wanted, dtype=np.int32)))

    # -- growing ----------------------------------------------------------------------------
    def added(self, segs: list[dict]) -> StepRows:
        """A copy with the steps of remembered segments (rows as `_tool_segment` returns them)
        put in their place, in the order given: after the steps of equal video and time, as a
        whole read and stable sort, then `insort_right` of each step, puts them."""
        new = [(seg, steps) for seg in segs if (steps := segment_steps(seg))]
        if not new:
            return self
        videos = list(self.videos)
        for seg, _ in new:
            i = bisect.bisect_left(videos, seg["video"])
            if i == len(videos) or videos[i] != seg["video"]:
                videos.insert(i, seg["video"])
        video = self.video
        if len(videos) != len(self.videos):  # new videos: the old indexes shift to their new rank
            remap = np.asarray([bisect.bisect_left(videos, v) for v in self.videos], dtype=np.int32)
            video = remap[self.video] if len(self.video) else self.video
        segments, words = list(self.segments), list(self.words)
        word_ix = self.__dict__.get("_word_index")
        if word_ix is None:
            word_ix = {w: i for i, w in enumerate(words)}
        word_ix = dict(word_ix)
        rows = []  # (video rank, t, arrival, segment, word)
        for seg, steps in new:
            v = bisect.bisect_left(videos, seg["video"])
            si = len(segments)
            segments.append(seg["id"])
            for t, w in steps:
                wi = word_ix.get(w)
                if wi is None:
                    wi = word_ix[w] = len(words)
                    words.append(w)
                rows.append((v, t, len(rows), si, wi))
        rows.sort(key=lambda r: (r[0], r[1], r[2]))
        at = []
        ranks = np.asarray([r[0] for r in rows], dtype=video.dtype)  # of the column's type: no copy of it per search
        los, his = np.searchsorted(video, ranks, "left"), np.searchsorted(video, ranks, "right")
        for (_, t, *_), lo, hi in zip(rows, los.tolist(), his.tolist()):  # after every old step of a smaller or equal (video, time)
            at.append(lo + int(np.searchsorted(self.t[lo:hi], t, "right")))
        out = StepRows(videos, segments, words,
                       np.insert(video, at, [r[0] for r in rows]).astype(np.int32),
                       np.insert(self.t, at, [r[1] for r in rows]).astype(np.float64),
                       np.insert(self.segment, at, [r[3] for r in rows]).astype(np.int32),
                       np.insert(self.word, at, [r[4] for r in rows]).astype(np.int32))
        out._word_index = word_ix
        out.lineage = self.lineage
        # what a log over these rows needs to derive its runs from the log over `self` (agent/
        # query/steplog.py) instead of from every step: where the new steps went, and from what
        out.grown = (weakref.ref(self), np.asarray(at, dtype=np.int64))
        return out
