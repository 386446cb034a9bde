// description: Every row of `videos` (for the code that needs them all; not offered by servers). The videos built into a participant's memory, in order, with their size and build time.
// params: participant
MATCH (v:Video)
WHERE v.participant = $participant
OPTIONAL MATCH (v)-[:HAS_SEGMENT]->(s:Segment)
RETURN v.id AS video, v.duration AS duration_s, v.n_turns AS turns, v.n_actions AS actions, count(s) AS segments,
       v.mode AS mode, v.build_seconds AS build_seconds
ORDER BY video
