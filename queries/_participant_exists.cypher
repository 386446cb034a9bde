// description: Whether the Participant node exists yet (1 or 0).
// params: participant
MATCH (p:Participant)
WHERE p.id = $participant
RETURN count(p) AS n
