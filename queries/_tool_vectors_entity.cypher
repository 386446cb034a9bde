// description: Every entity embedding of a participant, for exact top-k search in process.
// params: participant
MATCH (n:Entity)
WHERE n.participant = $participant AND n.status = 'active'
RETURN n.id AS id, n.emb AS emb
ORDER BY id
