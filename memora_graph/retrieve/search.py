"""Search primitives of the retrieval tools: exact vector top-k, keyword scoring, RRF fusion, dedup.

Every variant is a `SearchConfig`; the named recipes in `RECIPES` are the ones `memora perf
tools` measures side by side, so a reader sees every retrieval variant in one place:

- vector: "numpy" (exact cosine over the participant's embedding matrix, loaded once through a
  named query), "kuzu" (exact `array_cosine_similarity` inside Kùzu per call) or "hnsw" (Kùzu's
  HNSW index; optional, built on a copy by the benchmark only).
- keyword: "bm25" (Okapi BM25 over the same texts Kùzu's FTS index holds, scored in process),
  "fts" (a QUERY_FTS_INDEX call per search) or "none".
- fusion: reciprocal-rank fusion of the vector and keyword ranks plus a small graph term, so a
  record found by both signals beats one found by either alone.

The default ("inprocess") is the measured fastest (docs/findings/embedding-defaults.md, "Retrieval recipes").
`fts`, `kuzu` and `hnsw` use Kùzu per call and need its FTS (and HNSW) indexes, which a build
makes only when asked (`memora build --fts`, `memora index BANK --fts --hnsw`).
"""

from __future__ import annotations

import math
import os
from collections import Counter, defaultdict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from memora_graph.text import index_tokens

TABLES = ("segment", "entity", "place", "routine", "preference")  # the tables with vectors and BM25
DEFAULT_TOP_K = 10
MAX_TOP_K = 30


class SearchConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    vector: Literal["numpy", "kuzu", "hnsw"] = "numpy"
    keyword: Literal["bm25", "fts", "none"] = "bm25"
    rrf_k: int = 60
    graph_weight: float = 0.5  # a graph score of 1.0 is worth half a rank-1 RRF vote
    dedup_cosine: float = 0.95
    pool: int = 50  # candidates taken from each signal before fusion


RECIPES: dict[str, SearchConfig] = {
    "inprocess": SearchConfig(keyword="bm25"),  # the default: no Kùzu round trip to rank
    "fts": SearchConfig(keyword="fts"),  # keywords through Kùzu's full-text index
    "kuzu": SearchConfig(vector="kuzu", keyword="fts"),  # both signals computed inside Kùzu
    "hnsw": SearchConfig(vector="hnsw", keyword="fts"),  # needs `memora index BANK --fts --hnsw`
    "vector": SearchConfig(keyword="none"),
}
DEFAULT_RECIPE = "inprocess"
# From this many segments on, a participant whose database has the FTS and HNSW indexes opens with
# the "hnsw" recipe when no recipe is asked for; None: never (ask for it with --recipe hnsw).
# `memora perf scale` measures the crossover; no measured size has HNSW faster, so the switch is off
# until one does (docs/findings/scale-first-runs.md).
HNSW_MIN_SEGMENTS: int | None = None


# -- vectors ---------------------------------------------------------------------------------
UNIQUE_BLOCK = 64  # rows the distinct-rows product leaves to a plain product at the end (see VectorTable.sims)
UNIQUE_MIN_ROWS = 20_000  # smaller tables are scanned whole (a few MB: nothing to save)
UNIQUE_MAX_SHARE = 0.75  # kept only where at most this share of the rows is distinct
SCAN_MIN_ROWS = 32_768  # a product over this many rows or more is split across SCAN_THREADS threads
SCAN_THREADS = max(1, min(4, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))
_scan_pool: tuple[int, ThreadPoolExecutor] | None = None  # (the process that made it, the pool)


def _pool() -> ThreadPoolExecutor:
    """The threads that take the parts of a split product (made again in a forked child, where
    the parent's threads do not exist)."""
    global _scan_pool
    if _scan_pool is None or _scan_pool[0] != os.getpid():
        _scan_pool = (os.getpid(), ThreadPoolExecutor(max(1, SCAN_THREADS - 1), thread_name_prefix="memora-scan"))
    return _scan_pool[1]


def product(mat: np.ndarray, q: np.ndarray, threads: int | None = None) -> np.ndarray:
    """`mat @ q` (float32 rows, one vector), bit for bit, split by rows across `threads` threads
    (SCAN_THREADS by default) when `mat` has at least SCAN_MIN_ROWS rows. The scan is memory-bound
    (one thread streams ~8 GB/s here: 97 MB of distinct segment rows at 1,000 h); the threads share
    it, so the wall time falls and the CPU time stays. The parts start at multiples of
    UNIQUE_BLOCK rows and the last has more than one row, so each value is the one a single
    product gives (see VectorTable.sims); tests/retrieve/test_scale_structures.py checks it."""
    n = len(mat)
    threads = SCAN_THREADS if threads is None else threads
    if threads < 2 or n < SCAN_MIN_ROWS:
        return mat @ q
    step = -(-n // threads // UNIQUE_BLOCK) * UNIQUE_BLOCK
    cuts = list(range(0, n, step))
    if n - cuts[-1] < 2:  # a product of one row takes another path: the last part keeps two or more
        cuts.pop()
    cuts.append(n)
    out = np.empty(n, dtype=np.result_type(mat.dtype, q.dtype))
    parts = [(a, b) for a, b in zip(cuts, cuts[1:])]

    def part(ab: tuple[int, int]) -> None:
        np.matmul(mat[ab[0]:ab[1]], q, out=out[ab[0]:ab[1]])

    pending = [_pool().submit(part, ab) for ab in parts[1:]]
    part(parts[0])  # this thread takes the first part
    for f in pending:
        f.result()
    return out


class VectorTable:
    """The embedding matrix of one table of one participant (rows L2-normalized)."""

    _tail: tuple[np.ndarray, int] | None = None  # rows appended behind the matrix (`appended`), and how many

    @property
    def mat(self) -> np.ndarray:
        """Every row, as one array: rows appended behind a matrix left as it was (`appended`) are
        folded in first, into one array in memory grown by doubling (a copy of the whole
        matrix, paid once by the caller that needs it whole; a search does not)."""
        if self._tail is not None:
            tail, k = self._tail
            base = self._mat
            n0 = len(base)
            store = np.zeros((max(64, 2 * (n0 + k)), base.shape[1]), dtype=np.float32)
            store[:n0] = base
            store[n0:n0 + k] = tail[:k]
            self._mat, self._store, self._tail = store[:n0 + k], store, None
        return self._mat

    @mat.setter
    def mat(self, value: np.ndarray) -> None:
        self._mat, self._tail = value, None
        self.__dict__.pop("_store", None)

    @property
    def dim(self) -> int:
        return self._mat.shape[1]

    def _rows_from(self, start: int) -> np.ndarray:
        """`mat[start:]` without folding the appended rows in (a copy of those rows only)."""
        if self._tail is None:
            return self._mat[start:]
        tail, k = self._tail
        n0 = len(self._mat)
        if start >= n0:
            return tail[start - n0:k]
        return np.concatenate([self._mat[start:], tail[:k]])

    def __init__(self, ids: list[str], vectors: np.ndarray):
        self.ids = ids
        self.index = {i: n for n, i in enumerate(ids)}
        mat = np.asarray(vectors, dtype=np.float32).reshape(len(ids), -1) if ids else np.zeros((0, 1), np.float32)
        norms = np.linalg.norm(mat, axis=1, keepdims=True) if len(ids) else np.ones((0, 1), np.float32)
        self.mat = np.divide(mat, norms, out=np.zeros_like(mat), where=norms > 0)

    @classmethod
    def normalized(cls, ids: list[str], mat: np.ndarray) -> VectorTable:
        """A table from rows already L2-normalised by this class (a persisted, memory-mapped `mat`)."""
        table = cls.__new__(cls)  # a plain array over the mapping: indexing a np.memmap costs ~10 us a row
        table.ids, table.index, table.mat = ids, {i: n for n, i in enumerate(ids)}, np.asarray(mat)
        return table

    @classmethod
    def from_rows(cls, rows: list[dict]) -> VectorTable:
        rows = [r for r in rows if r["emb"] is not None]
        return cls([r["id"] for r in rows], np.asarray([r["emb"] for r in rows], dtype=np.float32))

    def __len__(self) -> int:
        return len(self.ids)

    def sims(self, q: np.ndarray) -> np.ndarray:
        """Cosine of every row with `q` (`mat @ q`). With the table's distinct rows attached
        (`with_unique`), the product is taken over the distinct rows of the first `head` rows and
        spread back, and over the rows from `head` on as they are; each value is the one `mat @ q`
        gives (BLAS computes a row's dot product the same wherever the row lies in a block of
        rows, and only the last rows of a product, fewer than a block, take another path: `head`
        is a multiple of UNIQUE_BLOCK and the rows after it are a product of their own, never of
        one row). `unique_rows` checks it before keeping the distinct rows, and
        tests/retrieve/test_scale_structures.py checks it bit for bit."""
        return self._sims(q, negate=False)

    def _sims(self, q: np.ndarray, negate: bool) -> np.ndarray:
        """`sims(q)`, or with `negate` its negation (exact: what `topk` partitions), made without
        a second pass over every row: the distinct rows' values are negated before they are
        spread back."""
        n = len(self.ids)
        if not n:
            return np.zeros(0, np.float32)
        unique = self.__dict__.get("_unique")
        if unique is None or n < unique[2]:
            s = product(self.mat, q)
            return np.negative(s, out=s) if negate else s
        rows, inverse, head = unique
        start = head if n - head != 1 else head - UNIQUE_BLOCK  # a product of one row takes another path
        u = product(rows, q)
        if negate:
            np.negative(u, out=u)
        s = np.empty(n, dtype=np.float32)
        np.take(u, inverse[:start], out=s[:start], mode="clip")  # every index is in range: no copy to check it
        if n > start:
            rest = self._rows_from(start) @ q
            s[start:] = np.negative(rest, out=rest) if negate else rest
        return s

    def with_unique(self, rows: np.ndarray, inverse: np.ndarray, head: int) -> VectorTable:
        """This table scanning its distinct rows (`unique_rows`' result, perhaps memory-mapped)."""
        if head % UNIQUE_BLOCK or head < UNIQUE_BLOCK or len(inverse) != head or len(rows) % UNIQUE_BLOCK:
            raise ValueError(f"distinct rows for {head} rows do not fit blocks of {UNIQUE_BLOCK}")
        # the indices as the platform's index type, in memory (2.9 MB at 1,000 h): np.take converted
        # the stored int32 ones at every search
        self._unique = (np.asarray(rows), np.asarray(inverse, dtype=np.intp), head)
        return self

    def unique_rows(self, checks: int = 4,
                    min_rows: int = UNIQUE_MIN_ROWS) -> tuple[np.ndarray, np.ndarray, int] | None:
        """(distinct rows of the first `head` rows, zero rows added up to a multiple of UNIQUE_BLOCK;
        each of those rows' index among them; `head`), or None where scanning them would not save
        much (fewer than `min_rows` rows, or more than UNIQUE_MAX_SHARE of them distinct) or where
        the values would not be those of `mat @ q` on this machine (checked on `checks` queries).
        Segments repeat: the same narrated action gives the same summary and vector (at 100 h of
        the synthetic participant, 10,443 distinct of 36,003)."""
        n = len(self.ids)
        head = n - n % UNIQUE_BLOCK
        if n < min_rows or head < UNIQUE_BLOCK:
            return None
        mat = np.ascontiguousarray(self.mat[:head])
        keys = mat.view(np.dtype((np.void, mat.dtype.itemsize * mat.shape[1]))).ravel()
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        if len(first) > UNIQUE_MAX_SHARE * head:
            return None
        width = -(-len(first) // UNIQUE_BLOCK) * UNIQUE_BLOCK
        rows = np.zeros((width, mat.shape[1]), dtype=np.float32)
        rows[:len(first)] = mat[first]
        got = (rows, inverse.astype(np.int32).ravel(), head)
        probe = VectorTable.normalized(self.ids, self.mat).with_unique(*got)
        rng = np.random.default_rng(0)
        for _ in range(checks):
            q = rng.standard_normal(self.mat.shape[1]).astype(np.float32)
            q /= np.linalg.norm(q)
            if not np.array_equal(probe.sims(q), self.mat @ q):
                return None
        return got

    def topk(self, q: np.ndarray, k: int) -> list[tuple[str, float]]:
        """Exact top-k by cosine; ties broken by id so results are deterministic."""
        neg = self._sims(q, negate=True)  # -sims(q), the array partitioned
        if not len(neg):
            return []
        k = min(k, len(neg))
        part = np.argpartition(neg, k - 1)[:k] if k < len(neg) else np.arange(len(neg))
        ids = self.ids
        order = sorted(zip(neg[part].tolist(), part.tolist()), key=lambda vi: (vi[0], ids[vi[1]]))
        return [(ids[i], -v) for v, i in order]

    def appended(self, rid: str, vector: np.ndarray) -> VectorTable:
        """This table with one more row (a remembered segment), updated in place. A matrix held in
        an array of this table's own with room behind its rows takes the row there; any other (a
        persisted, memory-mapped one: 553 MB at 1,000 h) is left as it is, and the row goes to a
        tail of appended rows grown by doubling (copying the matrix, and zeroing twice its size,
        took ~1.2 s at the first append after a writable open at 1,000 h). The ids and their index
        are copied once (they may be shared with what loaded them), then grow by one: an append
        costs the same at 1,000 h as at 10 h."""
        v = np.asarray(vector, dtype=np.float32).reshape(-1)
        norm = float(np.linalg.norm(v))
        v = v / norm if norm > 0 else v
        n = len(self.ids)
        if n == 0 and self._tail is None and self._mat.shape[1] != v.shape[0]:
            self.mat = np.zeros((0, v.shape[0]), dtype=np.float32)
        store = self.__dict__.get("_store")
        if self._tail is None and store is not None and store.shape[0] > n:
            store[n] = v
            self._mat = store[: n + 1]
        else:
            tail, k = self._tail or (np.zeros((64, self._mat.shape[1]), dtype=np.float32), 0)
            if k == len(tail):
                grown = np.zeros((2 * k, tail.shape[1]), dtype=np.float32)
                grown[:k] = tail
                tail = grown
            tail[k] = v
            self._tail = (tail, k + 1)
        if not self.__dict__.get("_owned"):
            self.ids, self.index, self._owned = list(self.ids), dict(self.index), True
        self.ids.append(rid)
        self.index[rid] = n
        return self

    def vec(self, rid: str) -> np.ndarray | None:
        n = self.index.get(rid)
        if n is None:
            return None
        unique = self.__dict__.get("_unique")
        if unique is not None and n < unique[2]:  # its distinct row: the same values, held in memory
            return unique[0][unique[1][n]]
        if self._tail is not None and n >= len(self._mat):
            return self._tail[0][n - len(self._mat)]
        return self._mat[n]

    def gather(self, rows: np.ndarray) -> np.ndarray:
        """`mat[rows]` (a copy; `rows` non-negative row numbers), read from the distinct rows where
        the table has them (the same float32 values, `unique_rows`): the scan keeps those in
        memory, while the rows of the whole matrix are memory-mapped (553 MB at 1,000 h), where
        each row gathered is a page to fault in."""
        rows = np.asarray(rows, dtype=np.intp)
        unique = self.__dict__.get("_unique")
        if unique is None:
            return self._take(rows)
        distinct, inverse, head = unique
        low = rows < head
        if low.all():
            return distinct[inverse[rows]]
        out = np.empty((len(rows), self.dim), dtype=np.float32)
        out[low] = distinct[inverse[rows[low]]]
        out[~low] = self._take(rows[~low])
        return out

    def _take(self, rows: np.ndarray) -> np.ndarray:
        """`mat[rows]`, the appended rows read from their tail (not folded in)."""
        if self._tail is None:
            return self._mat[rows]
        n0 = len(self._mat)
        behind = rows >= n0
        if not behind.any():
            return self._mat[rows]
        out = np.empty((len(rows), self.dim), dtype=np.float32)
        out[~behind] = self._mat[rows[~behind]]
        out[behind] = self._tail[0][rows[behind] - n0]
        return out


# -- keywords --------------------------------------------------------------------------------
class Bm25:
    """Okapi BM25 over a corpus, in process (k1 = 1.2, b = 0.75, as Kùzu's FTS).

    The postings are flat arrays (a term's documents and term counts between two offsets), so a
    search scores each query term's posting list in one vectorised pass, whatever its length (at
    1,000 h "take" is in a third of 360,000 segments), and the arrays persist as memory-mapped
    files (`arrays()` / `from_arrays`) that open without being parsed. Scores are those of the
    per-posting loop: the same float64 operations in the same order, terms added per document in
    the order the query's terms are visited."""

    def __init__(self, ids: list[str], texts: list[str], k1: float = 1.2, b: float = 0.75):
        postings: dict[str, list[tuple[int, int]]] = defaultdict(list)
        lengths = []
        for n, text in enumerate(texts):
            toks = index_tokens(text)
            lengths.append(len(toks))
            for t, c in Counter(toks).items():
                postings[t].append((n, c))
        terms = sorted(postings)
        sizes = np.fromiter((len(postings[t]) for t in terms), dtype=np.int64, count=len(terms))
        offsets = np.zeros(len(terms) + 1, dtype=np.int64)
        np.cumsum(sizes, out=offsets[1:])
        flat = [p for t in terms for p in postings[t]]
        docs = np.fromiter((d for d, _ in flat), dtype=np.int32, count=len(flat))
        tfs = np.fromiter((c for _, c in flat), dtype=np.int32, count=len(flat))
        avg = (sum(lengths) / len(lengths)) if lengths else 1.0
        self._set(ids, terms, offsets, docs, tfs, np.asarray(lengths, dtype=np.int64), avg, k1, b)

    def _set(self, ids, terms, offsets, docs, tfs, lengths, avg, k1, b) -> None:
        self.ids, self.k1, self.b, self.avg = ids, k1, b, avg
        self.terms = terms
        self.vocab = {t: i for i, t in enumerate(terms)}
        self.offsets, self.docs, self.tfs, self.lengths = (np.asarray(a) for a in (offsets, docs, tfs, lengths))
        self.n = len(ids)

    def arrays(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(JSON-ready header: ids, terms, k1, b, avg; the arrays: offsets, docs, tfs, lengths)."""
        return ({"ids": self.ids, "terms": self.terms, "k1": self.k1, "b": self.b, "avg": self.avg},
                {"offsets": self.offsets, "docs": self.docs, "tfs": self.tfs, "lengths": self.lengths})

    @classmethod
    def from_arrays(cls, header: dict, arrays: dict[str, np.ndarray]) -> Bm25:
        bm = cls.__new__(cls)
        bm._set(header["ids"], header["terms"], arrays["offsets"], arrays["docs"], arrays["tfs"], arrays["lengths"],
                header["avg"], header["k1"], header["b"])
        return bm

    def _slice(self, term: str) -> tuple[np.ndarray, np.ndarray]:
        """(documents, term counts) of `term`: the arrays' posting list, then the documents added since."""
        i = self.vocab.get(term)
        lo, hi = (0, 0) if i is None else (int(self.offsets[i]), int(self.offsets[i + 1]))
        docs, tfs = self.docs[lo:hi], self.tfs[lo:hi]
        more = self.__dict__.get("_added", {}).get(term)
        if more:
            docs = np.concatenate([docs, np.asarray([d for d, _ in more], dtype=np.int32)])
            tfs = np.concatenate([tfs, np.asarray([c for _, c in more], dtype=np.int32)])
        return docs, tfs

    def postings(self, term: str) -> list[tuple[int, int]]:
        """(document number, term count) of every document containing `term`."""
        docs, tfs = self._slice(term)
        return list(zip(docs.tolist(), tfs.tolist()))

    def added(self, rid: str, text: str) -> Bm25:
        """This index with one more document (a remembered segment), updated in place: its postings
        wait in a small overlay beside the arrays (sorted, perhaps memory-mapped: not rebuilt per
        document); the lengths grow by one."""
        toks = index_tokens(text)
        n = len(self.ids)
        if not self.__dict__.get("_owned"):  # the ids may be shared with what loaded them: copied once
            self.ids, self._owned = list(self.ids), True
            self._total = int(np.asarray(self.lengths, dtype=np.int64).sum())
        self.ids.append(rid)
        extra = self.__dict__.setdefault("_added", {})
        for t, c in Counter(toks).items():
            extra.setdefault(t, []).append((n, c))
        grown = self.__dict__.get("_lengths")  # the lengths grow by doubling, as VectorTable's rows
        if grown is None or grown.shape[0] <= n:
            grown = np.zeros(max(64, 2 * (n + 1)), dtype=np.int64)
            grown[:n] = self.lengths
        grown[n] = len(toks)
        self._lengths, self.lengths = grown, grown[: n + 1]
        self._total += len(toks)
        self.avg = float(self._total) / (n + 1)
        self.n = len(self.ids)
        return self

    def _norms(self) -> np.ndarray:
        """k1 * (1 - b + b * length / avg) of every document: the part of a posting's denominator
        that does not depend on the term, computed once per corpus (again after `added`), with
        the operations the per-posting formula applies, so that each value is the same."""
        got = self.__dict__.get("_norm_cache")
        if got is None or got[0] != (self.n, self.avg):
            lengths = np.asarray(self.lengths[: self.n])
            got = self._norm_cache = ((self.n, self.avg), self.k1 * (1 - self.b + self.b * lengths / self.avg))
        return got[1]

    def _idf(self, df: int) -> float:
        return math.log(1 + (self.n - df + 0.5) / (df + 0.5))

    def _scores(self, docs: np.ndarray, tf: np.ndarray, idf: float) -> np.ndarray:
        """A term's score in each of `docs` (its term counts `tf`): each value is the one the
        per-posting formula gives, whichever of the term's documents are scored with it."""
        tf = tf.astype(np.float64)
        return idf * tf * (self.k1 + 1) / (tf + self._norms()[docs])

    def _bound(self, tf: np.ndarray, idf: float) -> float:
        """More than any score of a term whose term counts are `tf` can reach: the score grows with
        the count and falls with the document's length, so its value at the largest count and
        the shortest document, with a margin far above the rounding of the five operations."""
        norms = self._norms()
        low = self.__dict__.get("_norm_min")
        if low is None or low[0] is not norms:
            low = self._norm_min = (norms, float(norms.min()))
        top = float(tf.max())
        return idf * top * (self.k1 + 1) / (top + low[1]) * (1 + 1e-9)

    def _pruned(self, found: list[tuple[np.ndarray, np.ndarray]], k: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(documents, scores) holding every document of the top `k` of a query of several terms
        (`found`: each term's documents and counts, in the order the terms are visited), scored
        only where another term than the longest posting list occurs; None where that cannot be
        shown. The longest list ("put": half the segments at 1,000 h) is read only at those
        documents (its documents are in increasing order: `searchsorted`); a document it alone
        names scores at most its bound, so where the k-th best of the others' documents scores
        more, none of those is among the k best nor tied with them, and each kept score is the
        sum the dense pass makes (the terms added in the order they are visited, from 0.0)."""
        big = max(range(len(found)), key=lambda i: len(found[i][0]))
        others = [found[i][0] for i in range(len(found)) if i != big]
        named = sum(len(d) for d in others)
        if named > len(found[big][0]) or named < k:
            return None  # little to save, or too few documents for a k-th
        if len(others) == 1:
            cand = others[0]
        else:  # the documents of the others, in increasing order, each once (np.unique took ~20 ms for 34,000 here)
            cand = np.sort(np.concatenate(others))
            cand = cand[np.concatenate(([True], cand[1:] != cand[:-1]))]
        if len(cand) < k:
            return None
        bdocs, btf = found[big]
        at = np.minimum(np.searchsorted(bdocs, cand), len(bdocs) - 1)
        inb = np.flatnonzero(bdocs[at] == cand)
        scores = np.zeros(len(cand), dtype=np.float64)
        for i, (docs, tf) in enumerate(found):
            idf = self._idf(len(docs))
            if i == big:
                scores[inb] += self._scores(cand[inb], btf[at[inb]], idf)
            else:
                where = np.searchsorted(cand, docs) if len(others) > 1 else slice(None)
                scores[where] += self._scores(docs, tf, idf)
        kth = np.partition(scores, len(scores) - k)[len(scores) - k]
        if not kth > self._bound(btf, self._idf(len(bdocs))):
            return None
        return cand, scores

    def search(self, query: str, k: int) -> list[tuple[str, float]]:
        if k < 1:
            return []
        found = []  # (documents, term counts) of each query term found, in the order the terms are visited
        for t in set(index_tokens(query)):
            docs, tf = self._slice(t)
            if len(docs):
                found.append((docs, tf))
        if not found:
            return []
        if len(found) == 1:  # a posting list names a document once: its scores are the documents'
            hit, s = found[0][0], self._scores(*found[0], self._idf(len(found[0][0])))
        elif (got := self._pruned(found, k)) is not None:
            hit, s = got
        else:
            scores, seen = np.zeros(self.n, dtype=np.float64), np.zeros(self.n, dtype=bool)
            for docs, tf in found:
                scores[docs] += self._scores(docs, tf, self._idf(len(docs)))  # terms added per document in the order they are visited
                seen[docs] = True
            hit = np.flatnonzero(seen)  # the scored documents (an eighth of the bytes of the scores to scan)
            s = scores[hit]
        if len(hit) > k:  # the k best, and every document tied with the k-th (ties go by id)
            kth = np.partition(s, len(s) - k)[len(s) - k]
            keep = s >= kth
            hit, s = hit[keep], s[keep]
        ids = self.ids
        best = sorted(zip(s.tolist(), hit.tolist()), key=lambda sd: (-sd[0], ids[sd[1]]))[:k]
        return [(ids[d], sc) for sc, d in best]


# -- fusion ----------------------------------------------------------------------------------
@dataclass
class Candidate:
    id: str
    similarity: float = 0.0  # cosine to the query, whether or not the vector signal ranked it
    vector_rank: int | None = None
    keyword: float | None = None
    keyword_rank: int | None = None
    graph: float | None = None
    fused: float = 0.0
    duplicates: list[str] = field(default_factory=list)

    def breakdown(self) -> dict:
        """Why this record was returned: each signal's raw score and rank, and the fused score."""
        return {
            "vector": round(self.similarity, 4), "vector_rank": self.vector_rank,
            "keyword": None if self.keyword is None else round(self.keyword, 4), "keyword_rank": self.keyword_rank,
            "graph": None if self.graph is None else round(self.graph, 4), "fused": round(self.fused, 6),
        }


def fuse(vector_hits: list[tuple[str, float]], keyword_hits: list[tuple[str, float]], table: VectorTable | None,
         q: np.ndarray | None, config: SearchConfig) -> dict[str, Candidate]:
    """Candidates from both signals with their ranks; cosine filled in for keyword-only hits."""
    cands: dict[str, Candidate] = {}
    for rank, (rid, sim) in enumerate(vector_hits, 1):
        cands[rid] = Candidate(rid, similarity=sim, vector_rank=rank)
    for rank, (rid, score) in enumerate(keyword_hits, 1):
        c = cands.setdefault(rid, Candidate(rid))
        c.keyword, c.keyword_rank = score, rank
        if c.vector_rank is None and table is not None and q is not None:
            v = table.vec(rid)
            c.similarity = float(v @ q) if v is not None else 0.0
    return cands


def rank(cands: dict[str, Candidate], config: SearchConfig) -> list[Candidate]:
    k = config.rrf_k
    for c in cands.values():
        c.fused = ((1.0 / (k + c.vector_rank)) if c.vector_rank else 0.0) + \
                  ((1.0 / (k + c.keyword_rank)) if c.keyword_rank else 0.0) + \
                  ((config.graph_weight * c.graph / (k + 1)) if c.graph else 0.0)
    return sorted(cands.values(), key=lambda c: (-c.fused, -c.similarity, c.id))


def dedup(ranked: list[Candidate], table: VectorTable | None, threshold: float, top_k: int) -> list[Candidate]:
    """Walk in rank order; a record whose embedding has cosine >= threshold with one already kept
    collapses into it (listed in its `duplicates`)."""
    if table is None or not ranked:
        return ranked[:top_k]
    rows = [table.index.get(c.id) for c in ranked]
    if None not in rows:
        vecs = table.gather(rows)  # one gather, not a row at a time
    else:  # a record without a vector: a zero row
        vecs = np.zeros((len(rows), table.dim), np.float32)
        have = [i for i, r in enumerate(rows) if r is not None]
        if have:
            vecs[have] = table.gather([rows[i] for i in have])
    gram = (vecs @ vecs.T).tolist()  # every pairwise cosine of the pool (rows are unit length or zero)
    kept: list[int] = []
    for i, c in enumerate(ranked):
        if kept and rows[i] is not None:
            row = gram[i]
            j = max(kept, key=row.__getitem__)
            if row[j] >= threshold:
                ranked[j].duplicates.append(c.id)
                continue
        if len(kept) < top_k:
            kept.append(i)  # once full, later records can still collapse into kept ones, never join
    return [ranked[i] for i in kept]
