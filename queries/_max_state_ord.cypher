// description: The highest state-history order number written so far (to resume numbering).
// params: participant
MATCH (s:StateEvent)
WHERE s.participant = $participant
RETURN coalesce(max(s.ord), 0) AS max_ord
