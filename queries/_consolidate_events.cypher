// description: A participant's narrated object observations (state history) with their entity and segment, in time order.
// params: participant
MATCH (e:Entity)-[:HAS_STATE]->(s:StateEvent)-[:OBSERVED_IN]->(g:Segment)
WHERE s.participant = $participant AND s.action <> ''
RETURN s.id AS id, s.entity AS entity, g.id AS segment, s.video AS video, s.turn AS turn, s.t AS t, s.ord AS ord,
       s.state AS state, s.location AS location, s.zone AS zone, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration,
       e.kind AS kind, e.name AS name, e.category AS category, e.is_fixture AS is_fixture,
       e.status AS status, e.merged_into AS merged_into
ORDER BY s.video, s.t, s.ord
