// description: Every row of `baseline_routines` (for the code that needs them all; not offered by servers). The consolidated routines of a participant with their supporting segments (Graph-2D pattern nodes, planning metrics).
// params: participant
MATCH (r:Routine)
WHERE r.participant = $participant
OPTIONAL MATCH (r)-[:SUPPORTED_BY]->(s:Segment)
RETURN r.id AS id, r.goal AS goal, r.activity_type AS activity_type, r.canonical_steps AS canonical_steps,
       r.key_objects AS key_objects, r.count AS count, r.confidence AS confidence, r.source AS source, collect(s.id) AS segments
ORDER BY id
