// description: One entity's state history (every observation) in time order.
// params: participant, entity
MATCH (e:Entity {id: $entity})-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration, s.op AS op, s.prev_location AS prev_location
ORDER BY video, t, h.ord
