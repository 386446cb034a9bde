// description: One entity's state history in time order, only the columns its summary needs (states, places, per video, moves); the full entries of the ones shown are read by id (_tool_history_entries).
// params: participant, entity
MATCH (e:Entity {id: $entity})-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state, s.location AS location
ORDER BY video, t, h.ord
