// description: The 10 s turns of one video in order (the baselines' activity records, a video at a time: `videos` lists them).
// params: participant, video
// example: memora run BANK baseline_segments -p participant P01 -p video P01_102
// bound: page video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(s:Segment)
WHERE v.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end,
       s.summary AS summary, s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
ORDER BY turn
