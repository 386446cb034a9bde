// Keyword (full-text) indexes, read only by the 'fts', 'kuzu' and 'hnsw' retrieval recipes (the
// default recipe, 'inprocess', scores keywords in process with BM25). Not built by default:
// built on request by `memora build BANK --fts` or `memora index BANK --fts`
// (Store.ensure_indexes(fts=True)), after the bulk load and outside any transaction (Kùzu
// requires it); rows added later join the index automatically. Kùzu strips digits from indexed
// text, so ids stay in their own columns and are matched exactly.
CALL CREATE_FTS_INDEX('Segment', 'segment_fts', ['summary', 'narrative'], stemmer := 'porter');
CALL CREATE_FTS_INDEX('Entity', 'entity_fts', ['name', 'kind', 'category'], stemmer := 'porter');
CALL CREATE_FTS_INDEX('Place', 'place_fts', ['name'], stemmer := 'porter');
CALL CREATE_FTS_INDEX('Routine', 'routine_fts', ['retrieval_text'], stemmer := 'porter');
CALL CREATE_FTS_INDEX('Preference', 'preference_fts', ['retrieval_text'], stemmer := 'porter');
