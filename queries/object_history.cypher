// description: An object's state history in one video, in time order (every observation, with the editor's decision): a video at a time (`videos` lists them; `get_object_history` summarises every video).
// params: participant, object, video
// example: memora run BANK object_history -p participant P01 -p object plate -p video P01_01
// bound: page video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(:Segment)<-[:OBSERVED_IN]-(s:StateEvent)<-[h:HAS_STATE]-(e:Entity)
WHERE v.participant = $participant AND (e.object_id = $object OR e.name = $object OR e.id = $object)
RETURN e.id AS entity, s.video AS video, s.turn AS turn, s.t AS t, s.state AS state, s.location AS location,
       s.held_by AS held_by, s.action AS action, s.narration AS narration, s.op AS op
ORDER BY s.t, h.ord
