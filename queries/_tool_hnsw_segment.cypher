// description: Approximate top-50 over the optional segment HNSW index (measured by memora perf tools).
// params: participant, vector
CALL QUERY_VECTOR_INDEX('Segment', 'segment_hnsw', $vector, 50)
WITH node AS n, distance
WHERE n.participant = $participant
RETURN n.id AS id, 1.0 - distance AS sim
ORDER BY sim DESC, id
