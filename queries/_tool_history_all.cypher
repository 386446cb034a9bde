// description: Every entity's state history, whole, (ordered as _tool_history_outline orders one entity's by retrieve/history.py, which reads them; written once into the persisted tool stores' history index: retrieve/history.py).
// params: participant
MATCH (e:Entity)-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant
RETURN e.id AS entity, s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration, s.op AS op, h.ord AS ord
