// HNSW vector indexes, read only by the 'hnsw' retrieval recipe. Not built by default: at these
// sizes (at most ~1.4k segments per participant) exact search is faster and exact (see `memora
// perf tools`, which builds these on a temporary copy to measure their latency and recall@10).
// Built on request by `memora index BANK --hnsw` (Store.ensure_indexes(hnsw=True)). Segment and
// Entity embeddings are never SET, so the index stays valid; never drop and re-create it in
// place (known Kùzu bug).
CALL CREATE_VECTOR_INDEX('Segment', 'segment_hnsw', 'emb', metric := 'cosine');
CALL CREATE_VECTOR_INDEX('Entity', 'entity_hnsw', 'emb', metric := 'cosine');
