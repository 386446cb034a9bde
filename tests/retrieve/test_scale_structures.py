"""The retrieval structures made to open and answer fast at 1,000 h give what the straightforward
versions give: BM25 over flat posting arrays scores as the per-posting loop, the compact
observation graph answers as the dict-of-sets one."""

from __future__ import annotations

import math
import random
from collections import Counter, defaultdict

from memora_graph.retrieve.search import Bm25
from memora_graph.text import index_tokens

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


def test_bm25_of_an_empty_corpus():
    bm = Bm25([], [])
    assert bm.search("take plate", 5) == []
