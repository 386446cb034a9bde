// description: The activity log of one video: one row per 10 s turn, in order.
// params: participant, video
// example: memora run BANK segments -p participant P01 -p video P01_102
// bound: page video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(s:Segment)
WHERE v.participant = $participant
RETURN s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end, s.location AS place, s.summary AS summary
ORDER BY s.turn
