// description: How many segments the memory holds (the live consolidation schedule counts new ones).
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN count(s) AS n
