"""The retrieval structures made to open and answer fast at 1,000 h give what the straightforward
versions give: BM25 over flat posting arrays scores as the per-posting loop, the compact
observation graph answers as the dict-of-sets one, the distinct-rows scan of a vector table gives
`mat @ q` bit for bit (tests/retrieve/test_history.py: the history index)."""

from __future__ import annotations

import importlib
import math
import random
from collections import Counter, defaultdict

import numpy as np

from memora_graph.embed import single_thread_blas
from memora_graph.retrieve.search import UNIQUE_BLOCK, Bm25, VectorTable, product
from memora_graph.text import index_tokens

search_module = importlib.import_module("memora_graph.retrieve.search")  # the package exports a tool of that name
WORDS = "take put wash plate bowl knife cut onion pan stir open close tap sponge rinse cup kettle fill pour".split()


def _reference_bm25(ids, texts, query, k, k1=1.2, b=0.75):
    """Okapi BM25 as first written: a dict of posting lists, scored posting by posting."""
    postings, lengths = defaultdict(list), []
    for n, text in enumerate(texts):
        toks = index_tokens(text)
        lengths.append(len(toks))
        for t, c in Counter(toks).items():
            postings[t].append((n, c))
    avg, n_docs = (sum(lengths) / len(lengths)) if lengths else 1.0, len(ids)
    scores = defaultdict(float)
    for t in set(index_tokens(query)):
        plist = postings.get(t)
        if not plist:
            continue
        idf = math.log(1 + (n_docs - len(plist) + 0.5) / (len(plist) + 0.5))
        for doc, tf in plist:
            norm = tf + k1 * (1 - b + b * lengths[doc] / avg)
            scores[doc] += idf * tf * (k1 + 1) / norm
    best = sorted(scores.items(), key=lambda kv: (-kv[1], ids[kv[0]]))[:k]
    return [(ids[d], s) for d, s in best]


def test_bm25_arrays_score_as_the_posting_loop():
    rng = random.Random(7)
    texts = [" ".join(rng.choice(WORDS) for _ in range(rng.randint(0, 12))) for _ in range(3000)]
    texts += ["take plate"] * 40  # many exact ties: broken by id
    ids = [f"P01_{i % 97:03d}#t{i:05d}" for i in range(len(texts))]
    bm = Bm25(ids, texts)
    header, arrays = bm.arrays()
    reopened = Bm25.from_arrays(header, arrays)
    for q in ["take plate", "wash the bowl with the sponge", "zebra", "", "cut cut onion", "take", *WORDS]:
        for k in (1, 5, 10, 50):
            want = _reference_bm25(ids, texts, q, k)
            assert bm.search(q, k) == want, (q, k)
            assert reopened.search(q, k) == want, (q, k)
    assert bm.postings("zebra") == [] and len(bm.postings("take")) > 100


def test_bm25_scores_as_the_posting_loop_after_each_added_document():
    """The per-document part of the denominator is computed once per corpus: a document added
    (live memory) changes the average length, and the next search scores with the new one."""
    rng = random.Random(3)
    texts = [" ".join(rng.choice(WORDS) for _ in range(rng.randint(1, 9))) for _ in range(400)]
    ids = [f"s{i:04d}" for i in range(len(texts))]
    bm = Bm25(ids[:300], texts[:300])
    for n in range(300, 400, 7):
        for m in range(n - (7 if n > 300 else 0), n):
            bm = bm.added(ids[m], texts[m])
        for q in ("take plate", "wash the bowl with the sponge", "kettle", "cut onion pan"):
            assert bm.search(q, 10) == _reference_bm25(ids[:n], texts[:n], q, 10), (n, q)


def test_bm25_reading_the_longest_posting_list_only_where_other_terms_occur_scores_as_the_posting_loop(monkeypatch):
    """A query of several terms scores the longest posting list ("take": most documents) only at
    the documents of its other terms where the k-th of those beats anything it alone can score.
    The k best come out as the posting loop gives them, ties at the k-th included, whether that
    shortcut was taken or not (a document of "take" alone scoring high: short, "take" repeated),
    k larger than the documents scored, and after documents are added."""
    rng = random.Random(11)
    filler = [w for w in WORDS if w != "take"]
    texts = [" ".join((["take"] if rng.random() < 0.5 else []) + rng.choices(filler, k=rng.randint(1, 10)))
             for _ in range(4000)]
    texts += [" ".join(["zinc", *rng.choices(filler, k=60)]) for _ in range(60)]  # a rare term in long documents
    texts += ["take plate"] * 60 + ["plate kettle"] * 30 + [" ".join(["take"] * 30)] * 5 + ["take"] * 5
    ids = [f"s{i:05d}" for i in range(len(texts))]
    taken = []
    pruned = Bm25._pruned
    monkeypatch.setattr(Bm25, "_pruned", lambda self, found, k: taken.append(pruned(self, found, k)) or taken[-1])
    queries = ["take plate", "take kettle sponge", "plate take take", "take onion", "take zebra plate", "take take",
               "take zinc"]  # its k best for k = 50 hold documents of "take" alone
    bm = Bm25(ids[:3900], texts[:3900])
    for n in (3900, len(texts)):
        if n > 3900:
            for m in range(3900, n):
                bm = bm.added(ids[m], texts[m])
        for q in queries:
            for k in (1, 3, 10, 50, 300, 6000):
                assert bm.search(q, k) == _reference_bm25(ids[:n], texts[:n], q, k), (n, q, k)
    assert any(t is not None for t in taken) and any(t is None for t in taken)  # both ways taken


def test_bm25_of_an_empty_corpus():
    bm = Bm25([], [])
    assert bm.search("take plate", 5) == []


def _reference_history(view, entity_id: str, max_entries: int) -> dict:
    """get_object_history's summary as first written: every entry read whole, summarised in Python."""
    from memora_graph.records import segment_id

    rows = view.store.query(
        "MATCH (e:Entity {id: $entity})-[h:HAS_STATE]->(s:StateEvent) WHERE e.participant = $p "
        "RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state, s.location AS location, "
        "s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to, s.relation AS relation, "
        "s.action AS action, s.narration AS narration, s.op AS op ORDER BY video, t, h.ord",
        {"entity": entity_id, "p": view.participant}).to_dicts()
    for r in rows:
        r["segment"] = segment_id(r["video"], int(r["turn"]))
    transitions = [{"video": c["video"], "t": c["t"], "from": p["location"], "to": c["location"],
                    "across_videos": c["video"] != p["video"], "segment_id": c["segment"], "event_id": c["id"]}
                   for p, c in zip(rows, rows[1:]) if c["location"] != p["location"] and c["location"]]
    history = [{"event_id": r["id"], "segment_id": r["segment"], "video": r["video"], "turn_id": r["turn"],
                "time_seconds": r["t"], "state": r["state"], "location": r["location"], "zone": r["zone"] or None,
                "held_by": r["held_by"] or None, "relative_to": r["relative_to"] or None,
                "relation": r["relation"] or None, "action": r["action"] or None, "narration": r["narration"],
                "editor_op": r["op"]} for r in rows]
    per_video = {}
    for r in rows:
        v = per_video.setdefault(r["video"], {"video": r["video"], "observations": 0, "first_t": r["t"], "last_t": r["t"],
                                              "states": [], "locations": [], "final_state": "", "final_location": ""})
        v["observations"] += 1
        v["last_t"], v["final_state"], v["final_location"] = r["t"], r["state"], r["location"]
        for key, val in (("states", r["state"]), ("locations", r["location"])):
            if val and val not in v[key]:
                v[key].append(val)
    return {"state_history": history[-max_entries:], "history_total": len(history),
            "location_transitions": transitions[-max_entries:], "videos": list(per_video.values()),
            "all_states_observed": sorted({r["state"] for r in rows if r["state"]}),
            "all_locations_observed": sorted({r["location"] for r in rows if r["location"]}),
            "evidence": [entity_id, *sorted({r["segment"] for r in rows})[:20]]}


def test_object_history_reads_only_what_it_shows_and_answers_as_before(small_bank, embedder):
    """get_object_history reads a thin outline of the whole history and the entries it shows
    whole; every entity's summary is the one reading every entry whole gave."""
    from memora_graph.retrieve import MemoryView, call_tool

    with MemoryView.open(small_bank[0], "P37", embedder, persist=False) as view:
        ranked = sorted(view.entities.values(), key=lambda e: (-(e["n_observations"] or 0), e["id"]))
        checked = 0
        for e in ranked[:25]:
            for m in (1, 7, 60):
                got = call_tool(view, "get_object_history", {"object_query": e["id"], "max_entries": m}).as_json()
                assert got["entity_id"] == e["id"]
                want = _reference_history(view, e["id"], m)
                assert {k: got[k] for k in want} == want, (e["id"], m)
                checked += want["history_total"] > m
        assert checked > 10  # histories longer than what is shown


def _repeating_table(n: int, distinct: int, seed: int = 0) -> VectorTable:
    """n unit rows drawn from `distinct` ones (segments repeat their narrated actions)."""
    rng = np.random.default_rng(seed)
    base = rng.standard_normal((distinct, 384)).astype(np.float32)
    mat = base[rng.integers(0, distinct, n)]
    return VectorTable([f"seg{i:06d}" for i in range(n)], mat)


def test_the_distinct_rows_scan_gives_every_value_and_rank_of_the_whole_scan():
    """Every cosine bit for bit, hence the same exact top-k (ties included: the same argpartition
    over the same values), at every row count after the last whole block, and after appends (a
    remembered segment's row)."""
    single_thread_blas()  # as a view runs
    rng = np.random.default_rng(1)
    queries = [q / np.linalg.norm(q) for q in rng.standard_normal((12, 384)).astype(np.float32)]
    queries.append(np.asarray(_repeating_table(10, 10, seed=0).mat[3]))  # equal to stored rows: ties
    for extra in (0, 1, 2, 5, UNIQUE_BLOCK - 1):
        whole = _repeating_table(20 * UNIQUE_BLOCK + extra, 150)
        unique = whole.unique_rows(min_rows=1)
        assert unique is not None and len(unique[0]) < len(whole) / 4
        fast = VectorTable.normalized(whole.ids, whole.mat).with_unique(*unique)
        for q in queries:
            assert np.array_equal(fast.sims(q), whole.mat @ q), extra
            assert fast.topk(q, 50) == whole.topk(q, 50)
        grown, plain = fast, whole
        for i in range(3):
            row = whole.mat[i * 7]
            grown, plain = grown.appended(f"new{i}", row), plain.appended(f"new{i}", row)
            for q in queries[:4]:
                assert np.array_equal(grown.sims(q), plain.mat @ q), (extra, i)
                assert grown.topk(q, 20) == plain.topk(q, 20)


def test_appends_leave_a_mapped_matrix_mapped_and_give_the_values_of_the_whole(tmp_path):
    """Rows appended to a memory-mapped table (the persisted segment vectors a writable server
    reads) go behind it, the mapping left as it is (copying it took ~1.2 s and 1.1 GB at 1,000 h);
    sims, top-k, `vec` and `gather` give the values of the whole matrix with the rows in it, bit
    for bit, past several growths of the appended rows; a caller asking for `mat` gets them all."""
    single_thread_blas()
    whole = _repeating_table(20 * UNIQUE_BLOCK + 3, 150, seed=4)
    np.save(tmp_path / "m.npy", np.ascontiguousarray(whole.mat))
    mapped = np.load(tmp_path / "m.npy", mmap_mode="r")
    fast = VectorTable.normalized(list(whole.ids), mapped).with_unique(*whole.unique_rows(min_rows=1))
    plain = VectorTable.normalized(list(whole.ids), np.array(whole.mat))
    rng = np.random.default_rng(9)
    queries = [q / np.linalg.norm(q) for q in rng.standard_normal((3, 384)).astype(np.float32)]
    for i in range(150):  # the appended rows' array grows 64 -> 128 -> 256
        row = rng.standard_normal(384).astype(np.float32) if i % 3 else np.asarray(whole.mat[i])
        fast, plain = fast.appended(f"new{i}", row), plain.appended(f"new{i}", row)
        if i in (0, 63, 64, 149):
            assert np.shares_memory(fast._mat, mapped), "the mapped matrix was copied"
            for q in queries:
                assert np.array_equal(fast.sims(q), plain.mat @ q), i
                assert fast.topk(q, 20) == plain.topk(q, 20)
            n = len(plain)
            for rows in (rng.integers(0, n, 50), np.arange(n - 70, n)):
                assert fast.gather(rows).tobytes() == plain.mat[rows].tobytes()
            assert fast.vec(f"new{i}").tobytes() == plain.vec(f"new{i}").tobytes()
    assert np.array_equal(fast.mat, plain.mat) and len(fast.mat) == len(whole.ids) + 150


def _reference_topk(table: VectorTable, q: np.ndarray, k: int) -> list[tuple[str, float]]:
    """Exact top-k as first written: argpartition of the negated product, sorted by score then id."""
    s = table.mat @ q
    k = min(k, len(s))
    part = np.argpartition(-s, k - 1)[:k] if k < len(s) else np.arange(len(s))
    return [(table.ids[i], float(s[i])) for i in sorted(part, key=lambda i: (-float(s[i]), table.ids[i]))]


def test_a_product_split_across_threads_gives_the_single_product_bit_for_bit(monkeypatch):
    """The parts start at whole blocks and the last keeps two rows or more, so every value is the
    one `mat @ q` gives; the top-k (ties among repeated rows included) is the one first written."""
    single_thread_blas()
    monkeypatch.setattr(search_module, "SCAN_MIN_ROWS", 2)
    rng = np.random.default_rng(5)
    queries = [q / np.linalg.norm(q) for q in rng.standard_normal((4, 384)).astype(np.float32)]
    for n in (2, 63, 64, 65, 66, 129, 7 * UNIQUE_BLOCK + 1, 1000, 4099):
        mat = rng.standard_normal((n, 384)).astype(np.float32)
        for threads in (2, 3, 4):
            for q in queries:
                assert np.array_equal(product(mat, q, threads), mat @ q), (n, threads)
    monkeypatch.setattr(search_module, "SCAN_THREADS", 3)
    for extra in (0, 1, 3):
        whole = _repeating_table(40 * UNIQUE_BLOCK + extra, 200, seed=extra)
        fast = VectorTable.normalized(whole.ids, whole.mat).with_unique(*whole.unique_rows(min_rows=1))
        for q in [*queries, np.asarray(whole.mat[5])]:  # a stored row: ties at the top
            for k in (1, 10, 50, 200):
                want = _reference_topk(whole, q, k)
                assert whole.topk(q, k) == want and fast.topk(q, k) == want, (extra, k)


def test_rows_read_from_the_distinct_rows_are_the_rows_of_the_matrix():
    """`vec` and `gather` (what fusion and dedup read) give each row's float32 values bit for bit
    from the distinct rows, for rows before and after `head` and after appends, and dedup over
    them collapses and keeps what it does over the whole matrix."""
    from memora_graph.retrieve.search import Candidate, dedup

    for extra in (0, 1, 5):
        whole = _repeating_table(20 * UNIQUE_BLOCK + extra, 150, seed=extra)
        fast = VectorTable.normalized(whole.ids, np.array(whole.mat)).with_unique(*whole.unique_rows(min_rows=1))
        plain = VectorTable.normalized(whole.ids, np.array(whole.mat))
        for i in range(2):
            row = whole.mat[i * 11]
            fast, plain = fast.appended(f"new{i}", row), plain.appended(f"new{i}", row)
        n = len(plain)
        for rid in [*plain.ids[:: 37], *plain.ids[-UNIQUE_BLOCK - 3:], "missing"]:
            a, b = fast.vec(rid), plain.vec(rid)
            assert (a is None and b is None) or a.tobytes() == b.tobytes(), rid
        rng = np.random.default_rng(extra)
        for rows in (rng.integers(0, n, 80), np.arange(n - 4, n), np.arange(0, n, 97), np.zeros(0, np.intp)):
            assert fast.gather(rows).tobytes() == plain.mat[rows].tobytes()
        q = np.asarray(whole.mat[3])
        pool = [c for c, _ in plain.topk(q, 60)] + ["missing", plain.ids[-1]]
        got = dedup([Candidate(c) for c in pool], fast, 0.95, 10)
        want = dedup([Candidate(c) for c in pool], plain, 0.95, 10)
        assert [(c.id, c.duplicates) for c in got] == [(c.id, c.duplicates) for c in want]
        assert any(c.duplicates for c in want)  # repeated rows collapsed


def test_tables_mostly_distinct_or_small_are_scanned_whole():
    assert _repeating_table(20 * UNIQUE_BLOCK, 20 * UNIQUE_BLOCK * 10).unique_rows(min_rows=1) is None
    assert _repeating_table(5 * UNIQUE_BLOCK, 10).unique_rows() is None  # under UNIQUE_MIN_ROWS


def _used_with_reference(rows: list[dict], entity: str, k: int) -> list[tuple[str, int]]:
    """The entities seen in the most of `entity`'s segments, ties by id: counted from the rows."""
    by_segment = defaultdict(set)
    for r in rows:
        by_segment[r["segment"]].add(r["entity"])
    counts = Counter(o for es in by_segment.values() if entity in es for o in es if o != entity)
    return sorted(counts.items(), key=lambda ec: (-ec[1], ec[0]))[:k]


def test_used_with_counts_shared_segments_ties_by_id_from_arrays_and_with_added_moments(tmp_path):
    from memora_graph.retrieve.graph import ObservationGraph

    rng = random.Random(3)
    ents = [f"e{n:03d}" for n in range(60)]
    rows = [{"segment": f"v{s // 50}#t{s % 50}", "entity": e, "location": rng.choice(["sink", "hob", ""]), "n": 1}
            for s in range(2_000) for e in rng.sample(ents[:8] if s % 3 else ents, rng.randint(1, 5))]
    graph = ObservationGraph(rows)
    header, arrays = graph.arrays()
    for name, a in arrays.items():
        np.save(tmp_path / f"{name}.npy", a)
    mapped = ObservationGraph.from_arrays(header, {n: np.load(tmp_path / f"{n}.npy", mmap_mode="r") for n in arrays})
    ties = 0
    for e in ents + ["unknown"]:
        for k in (1, 5, 80):
            want = _used_with_reference(rows, e, k)
            assert graph.used_with(e, k) == want == mapped.used_with(e, k), (e, k)
        counts = [c for _, c in _used_with_reference(rows, e, 80)]
        ties += len(counts) - len(set(counts))
    assert ties > 100, "the rows give many ties to break by id"
    added = [("e001", "sink"), ("e059", "hob"), ("e030", "")]
    mapped.add("v99#t0", added)
    rows += [{"segment": "v99#t0", "entity": e, "location": loc, "n": 1} for e, loc in added]
    for e in ("e001", "e030", "e059", "e002"):
        assert mapped.used_with(e, 5) == _used_with_reference(rows, e, 5), e
    by_segment = defaultdict(set)  # each segment's entities, from the rows
    for r in rows:
        by_segment[r["segment"]].add(r["entity"])
    asked = [*sorted(by_segment), "v0#t0", "v3#t7", "v99#t0", "unknown", "v0#t0-longer-than-any-id", ""]
    want = [by_segment.get(x) for x in asked]
    assert mapped.segment_entities.many(asked) == want == [mapped.segment_entities.get(x) for x in asked]
    assert mapped.segment_entities.many([]) == []


def test_find_sorted_finds_every_key_and_no_other_whatever_its_width():
    """A sorted id array is searched with keys shorter, as wide as and wider than its strings
    (a remembered segment id is often longer than a build's): the right position, or None."""
    from memora_graph.retrieve.rows import find_sorted

    ids = sorted({f"P01_{v:03d}#t{t:04d}" for v in range(40) for t in range(0, 300, 7)})
    keys = np.asarray(ids, dtype=f"<U{max(map(len, ids))}")
    for n, i in enumerate(ids):
        assert find_sorted(keys, i) == n
    for missing in ["live-perf#t0012", "P01_000#t0001", "P01_999#t9999", "P", "", "P01_039#t0294x"]:
        assert find_sorted(keys, missing) is None
    assert find_sorted(np.asarray(ids, dtype=object), ids[5]) == 5  # not a fixed-width array: searched as is
    assert find_sorted(np.asarray([], dtype="<U1"), "x") is None


def test_find_sorted_many_answers_as_find_sorted_does_key_by_key():
    """One search for many keys gives each key the position `find_sorted` gives it: present,
    missing, wider than the array, empty, repeated, in any order, and on an empty array."""
    from memora_graph.retrieve.rows import find_sorted, find_sorted_many

    ids = sorted({f"P01_{v:03d}#t{t:04d}" for v in range(40) for t in range(0, 300, 7)})
    keys = np.asarray(ids, dtype=f"<U{max(map(len, ids))}")
    asked = [ids[-1], "live-perf#t0012", ids[0], "", "P01_039#t0294x", ids[7], ids[7], "P", "zzz"]
    want = [find_sorted(keys, k) for k in asked]
    assert find_sorted_many(keys, asked) == want
    assert want[0] == len(ids) - 1 and want[1] is None and want[5] == 7
    objects = np.asarray(ids, dtype=object)
    assert find_sorted_many(objects, asked) == [find_sorted(objects, k) for k in asked]
    assert find_sorted_many(np.asarray([], dtype="<U1"), ["x", ""]) == [None, None]
    assert find_sorted_many(keys, []) == []
    with_empty = np.asarray(["", "a", "b"], dtype="<U1")  # an empty key that is there is found
    assert find_sorted_many(with_empty, ["", "ab", "b"]) == [find_sorted(with_empty, k) for k in ["", "ab", "b"]] == [0, None, 2]
