// description: The full state-history entries of one entity with the given ids (those a history call shows).
// params: participant, entity, ids
MATCH (e:Entity {id: $entity})-[:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant AND s.id IN $ids
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration, s.op AS op
