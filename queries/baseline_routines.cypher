// description: The consolidated routines of a participant with their supporting segments (Graph-2D pattern nodes, planning metrics) (at most 1000 rows).
// params: participant
// example: memora run BANK baseline_routines -p participant P01
// bound: limit 1000
MATCH (r:Routine)
WHERE r.participant = $participant
OPTIONAL MATCH (r)-[:SUPPORTED_BY]->(s:Segment)
RETURN r.id AS id, r.goal AS goal, r.activity_type AS activity_type, r.canonical_steps AS canonical_steps,
       r.key_objects AS key_objects, r.count AS count, r.confidence AS confidence, r.source AS source, collect(s.id) AS segments
ORDER BY id
LIMIT 1000
