// description: The last $limit entries of one entity's state history, whole, newest first (those a history call shows; the rest is summarised from _tool_history_outline).
// params: participant, entity, limit
MATCH (e:Entity {id: $entity})-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration, s.op AS op
ORDER BY video DESC, t DESC, h.ord DESC
LIMIT $limit
