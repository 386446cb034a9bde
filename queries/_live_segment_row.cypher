// description: One segment's vector and texts (a reader appends a remembered segment to what it loaded; the id bound in the pattern: a primary-key lookup).
// params: participant, id
MATCH (s:Segment {id: $id})
WHERE s.participant = $participant
RETURN s.id AS id, s.emb AS emb, s.summary AS summary, s.narrative AS narrative
