// description: One segment's vector and texts (a reader appends a remembered segment to what it loaded).
// params: participant, id
MATCH (s:Segment)
WHERE s.participant = $participant AND s.id = $id
RETURN s.id AS id, s.emb AS emb, s.summary AS summary, s.narrative AS narrative
