// description: The text of every segment (summary and narrative), for the in-process keyword index.
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.summary AS summary, s.narrative AS narrative
ORDER BY id
