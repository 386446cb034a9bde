// description: Keyword (BM25) top-50 over the entity full-text index.
// params: participant, query
CALL QUERY_FTS_INDEX('Entity', 'entity_fts', $query)
WITH node AS n, score
WHERE n.participant = $participant AND n.status = 'active'
RETURN n.id AS id, score
ORDER BY score DESC, id
LIMIT 50
