// description: The explorer's state histories: every state event, with its object and the segment it was observed in.
// params: participant
MATCH (e:Entity)-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant
OPTIONAL MATCH (s)-[:OBSERVED_IN]->(g:Segment)
RETURN e.id AS entity, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state, s.location AS location,
       s.held_by AS held_by, s.action AS action, s.narration AS narration, s.op AS op, g.id AS segment
ORDER BY video, t, entity, h.ord
