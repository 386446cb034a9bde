// description: Each video's length, turns and last segment, where a live writer continues it.
// params: participant
MATCH (v:Video)
WHERE v.participant = $participant
OPTIONAL MATCH (v)-[:HAS_SEGMENT]->(s:Segment)
RETURN v.id AS video, v.duration AS duration, v.n_turns AS n_turns, v.n_actions AS n_actions,
       count(s) AS segments, max(s.turn) AS last_turn
ORDER BY video
