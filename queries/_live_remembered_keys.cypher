// description: Every client key a participant's remembers were acknowledged under (a live writer holds them in memory: a new key is told apart from a retry without a statement).
// params: participant
MATCH (r:Remembered)
WHERE r.participant = $participant
RETURN r.id AS id
