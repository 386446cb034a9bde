// description: Record counts per memory store for one participant (one row).
// params: participant
// example: memora run BANK store_counts -p participant P01
// bound: limit 1
MATCH (v:Video) WHERE v.participant = $participant
WITH count(v) AS videos
OPTIONAL MATCH (s:Segment) WHERE s.participant = $participant
WITH videos, count(s) AS segments
OPTIONAL MATCH (p:Place) WHERE p.participant = $participant
WITH videos, segments, count(p) AS places
OPTIONAL MATCH (e:Entity) WHERE e.participant = $participant
WITH videos, segments, places, count(e) AS entity_records, sum(CASE WHEN e.status = 'active' THEN 1 ELSE 0 END) AS entities
OPTIONAL MATCH (x:StateEvent) WHERE x.participant = $participant
WITH videos, segments, places, entity_records, entities, count(x) AS state_events
OPTIONAL MATCH (r:Routine) WHERE r.participant = $participant
WITH videos, segments, places, entity_records, entities, state_events, count(r) AS routines
OPTIONAL MATCH (f:Preference) WHERE f.participant = $participant
RETURN videos, segments, places, entity_records, entities, state_events, routines, count(f) AS preferences
LIMIT 1
