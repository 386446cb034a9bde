// description: Every entity id of a participant (to check the evidence a processor cites).
// params: participant
MATCH (e:Entity)
WHERE e.participant = $participant
RETURN e.id AS id
