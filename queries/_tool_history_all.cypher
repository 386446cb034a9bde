// description: Every entity's state history, only the columns the history summary needs (written once into the persisted tool stores: retrieve/history.py); ordered as _tool_history_outline orders one entity's.
// params: participant
MATCH (e:Entity)-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant
RETURN e.id AS entity, s.id AS id, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state,
       s.location AS location, h.ord AS ord
ORDER BY entity, video, t, ord
