// description: The segments in which an object changed location, with where it came from and went.
// params: participant, object
// example: memora run BANK location_changes -p participant P01 -p object plate
// bound: page object
MATCH (e:Entity)-[:HAS_STATE]->(s:StateEvent)-[:OBSERVED_IN]->(g:Segment)
WHERE e.participant = $participant AND (e.object_id = $object OR e.name = $object)
  AND s.prev_location <> '' AND s.location <> s.prev_location
RETURN g.id AS segment, g.video AS video, g.t_start AS t_start, s.prev_location AS moved_from,
       s.location AS moved_to, s.narration AS narration
ORDER BY g.video, g.t_start
