// description: The segments of one video in which an object changed location, with where it came from and went: a video at a time (`videos` lists them).
// params: participant, object, video
// example: memora run BANK location_changes -p participant P01 -p object plate -p video P01_109
// (the moves are kept after the match: filtered inside it, Kùzu joined from the objects, not the video: 142 -> 11 ms at 1,000 h)
// bound: page video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(g:Segment)<-[:OBSERVED_IN]-(s:StateEvent)<-[:HAS_STATE]-(e:Entity)
WHERE v.participant = $participant AND (e.object_id = $object OR e.name = $object)
WITH g, s WHERE s.prev_location <> '' AND s.location <> s.prev_location
RETURN g.id AS segment, g.video AS video, g.t_start AS t_start, s.prev_location AS moved_from,
       s.location AS moved_to, s.narration AS narration
ORDER BY t_start
