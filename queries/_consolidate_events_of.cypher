// description: The narrated object observations (state history) of some of a participant's videos, with their entity and segment (consolidation reads a participant a batch of videos at a time and orders them itself).
// params: participant, videos
MATCH (e:Entity)-[:HAS_STATE]->(s:StateEvent)-[:OBSERVED_IN]->(g:Segment)
WHERE s.participant = $participant AND s.video IN $videos AND s.action <> ''
RETURN s.id AS id, s.entity AS entity, g.id AS segment, s.video AS video, s.turn AS turn, s.t AS t, s.ord AS ord,
       s.state AS state, s.location AS location, s.zone AS zone, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action, s.narration AS narration,
       e.kind AS kind, e.name AS name, e.category AS category, e.is_fixture AS is_fixture
