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

The default ("inprocess") is the measured fastest: on the 18-participant bank, exact numpy top-k
takes ~0.1 ms where a Kùzu brute-force or HNSW query takes ~3 ms (HNSW recall@10 ~0.97), and an
FTS query costs 2-8 ms per store, which alone breaks a 5 ms budget for `search` (five stores).
`fts`, `kuzu` and `hnsw` use Kùzu per call and need its FTS (and HNSW) indexes, which a build
makes only when asked (`memora build --fts`, `memora index BANK --fts --hnsw`).
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from memora_graph.text import index_tokens

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
# `memora perf scale` (README "Memory at scale"): at 3,612 and 10,801 segments (10 and 30 h of P01)
# the in-process recipe was cheaper. A first 100 h run (36,003 segments, on code since improved:
# persisted stores, one BLAS thread) had HNSW cheaper (median tool p95 45.0 against 64.4 ms CPU)
# and set 36,000 here; re-measured on this code, the in-process recipe is as cheap or cheaper at
# 100 h (47.8 against 51.0) and at 300 h (108,005 segments: 110.5 against 124.3, and cheaper in CPU
# p50 on all 8 tools). No measured size has HNSW faster, so the switch is off until one does.
HNSW_MIN_SEGMENTS: int | None = None


# -- vectors ---------------------------------------------------------------------------------
class VectorTable:
    """The embedding matrix of one table of one participant (rows L2-normalized)."""

    def __init__(self, ids: list[str], vectors: np.ndarray):
        self.ids = ids
        self.index = {i: n for n, i in enumerate(ids)}
        mat = np.asarray(vectors, dtype=np.float32).reshape(len(ids), -1) if ids else np.zeros((0, 1), np.float32)
        norms = np.linalg.norm(mat, axis=1, keepdims=True) if len(ids) else np.ones((0, 1), np.float32)
        self.mat = np.divide(mat, norms, out=np.zeros_like(mat), where=norms > 0)

    @classmethod
    def normalized(cls, ids: list[str], mat: np.ndarray) -> VectorTable:
        """A table from rows already L2-normalised by this class (a persisted, memory-mapped `mat`)."""
        table = cls.__new__(cls)
        table.ids, table.index, table.mat = ids, {i: n for n, i in enumerate(ids)}, mat
        return table

    @classmethod
    def from_rows(cls, rows: list[dict]) -> VectorTable:
        rows = [r for r in rows if r["emb"] is not None]
        return cls([r["id"] for r in rows], np.asarray([r["emb"] for r in rows], dtype=np.float32))

    def __len__(self) -> int:
        return len(self.ids)

    def sims(self, q: np.ndarray) -> np.ndarray:
        return self.mat @ q if len(self.ids) else np.zeros(0, np.float32)

    def topk(self, q: np.ndarray, k: int) -> list[tuple[str, float]]:
        """Exact top-k by cosine; ties broken by id so results are deterministic."""
        s = self.sims(q)
        if not len(s):
            return []
        k = min(k, len(s))
        part = np.argpartition(-s, k - 1)[:k] if k < len(s) else np.arange(len(s))
        order = sorted(part, key=lambda i: (-float(s[i]), self.ids[i]))
        return [(self.ids[i], float(s[i])) for i in order]

    def appended(self, rid: str, vector: np.ndarray) -> VectorTable:
        """This table with one more row (a remembered segment). The matrix grows by doubling
        behind the rows in use, so a stream of appends copies it O(log n) times, not per row."""
        v = np.asarray(vector, dtype=np.float32).reshape(-1)
        norm = float(np.linalg.norm(v))
        v = v / norm if norm > 0 else v
        n = len(self.ids)
        store = self.__dict__.get("_store")
        if store is None or store.shape[0] <= n or store.shape[1] != v.shape[0]:
            width = v.shape[0] if n == 0 else self.mat.shape[1]
            store = np.zeros((max(64, 2 * (n + 1)), width), dtype=np.float32)
            store[:n] = self.mat
        store[n] = v
        out = VectorTable.normalized([*self.ids, rid], store[: n + 1])
        out._store = store
        return out

    def vec(self, rid: str) -> np.ndarray | None:
        n = self.index.get(rid)
        return None if n is None else self.mat[n]


# -- keywords --------------------------------------------------------------------------------
class Bm25:
    """Okapi BM25 over a small corpus, in process (k1 = 1.2, b = 0.75, as Kùzu's FTS)."""

    def __init__(self, ids: list[str], texts: list[str], k1: float = 1.2, b: float = 0.75):
        self.ids, self.k1, self.b = ids, k1, b
        self.postings: dict[str, list[tuple[int, int]]] = defaultdict(list)
        self.lengths = []
        for n, text in enumerate(texts):
            toks = index_tokens(text)
            self.lengths.append(len(toks))
            for t, c in Counter(toks).items():
                self.postings[t].append((n, c))
        self.avg = (sum(self.lengths) / len(self.lengths)) if self.lengths else 1.0
        self.n = len(ids)

    def state(self) -> dict:
        """Everything `search` reads, as JSON-ready values (persisted next to the bank)."""
        return {"ids": self.ids, "k1": self.k1, "b": self.b, "lengths": self.lengths, "avg": self.avg,
                "postings": {t: [list(p) for p in plist] for t, plist in self.postings.items()}}

    @classmethod
    def from_state(cls, state: dict) -> Bm25:
        bm = cls.__new__(cls)
        bm.ids, bm.k1, bm.b, bm.lengths, bm.avg = state["ids"], state["k1"], state["b"], state["lengths"], state["avg"]
        bm.postings = {t: [tuple(p) for p in plist] for t, plist in state["postings"].items()}
        bm.n = len(bm.ids)
        return bm

    def added(self, rid: str, text: str) -> Bm25:
        """This index with one more document (a remembered segment), updated in place."""
        toks = index_tokens(text)
        n = len(self.ids)
        self.ids = [*self.ids, rid]
        for t, c in Counter(toks).items():
            self.postings.setdefault(t, []).append((n, c))
        self.lengths.append(len(toks))
        self.avg = sum(self.lengths) / len(self.lengths)
        self.n = len(self.ids)
        return self

    def search(self, query: str, k: int) -> list[tuple[str, float]]:
        scores: dict[int, float] = defaultdict(float)
        for t in set(index_tokens(query)):
            plist = self.postings.get(t)
            if not plist:
                continue
            idf = math.log(1 + (self.n - len(plist) + 0.5) / (len(plist) + 0.5))
            for doc, tf in plist:
                norm = tf + self.k1 * (1 - self.b + self.b * self.lengths[doc] / self.avg)
                scores[doc] += idf * tf * (self.k1 + 1) / norm
        best = sorted(scores.items(), key=lambda kv: (-kv[1], self.ids[kv[0]]))[:k]
        return [(self.ids[d], s) for d, s in best]


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
    vecs = np.stack([table.mat[r] if r is not None else np.zeros(table.mat.shape[1], np.float32) for r in rows])
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
