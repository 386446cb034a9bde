// description: Every place embedding of a participant, for exact top-k search in process.
// params: participant
MATCH (n:Place)
WHERE n.participant = $participant
RETURN n.id AS id, n.emb AS emb
ORDER BY id
