// description: The videos built into a participant's memory, in order, with their size and build time (at most 10000 rows: the pages of the per-video queries).
// params: participant
// bound: limit 10000
// example: memora run BANK videos -p participant P01
MATCH (v:Video)
WHERE v.participant = $participant
OPTIONAL MATCH (v)-[:HAS_SEGMENT]->(s:Segment)
RETURN v.id AS video, v.duration AS duration_s, v.n_turns AS turns, v.n_actions AS actions, count(s) AS segments,
       v.mode AS mode, v.build_seconds AS build_seconds
ORDER BY video
LIMIT 10000
