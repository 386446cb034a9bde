// description: An object's state history in time order (every observation, with the editor's decision).
// params: participant, object
// example: memora run BANK object_history -p participant P01 -p object plate
// bound: page object
MATCH (e:Entity)-[h:HAS_STATE]->(s:StateEvent)
WHERE e.participant = $participant AND (e.object_id = $object OR e.name = $object OR e.id = $object)
RETURN e.id AS entity, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state, s.location AS location,
       s.held_by AS held_by, s.action AS action, s.narration AS narration, s.op AS op
ORDER BY s.video, s.t, h.ord
