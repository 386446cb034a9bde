// description: Keyword (BM25) top-50 over the segment full-text index.
// params: participant, query
CALL QUERY_FTS_INDEX('Segment', 'segment_fts', $query)
WITH node AS n, score
WHERE n.participant = $participant
RETURN n.id AS id, score
ORDER BY score DESC, id
LIMIT 50
