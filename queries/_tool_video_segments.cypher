// description: Every activity record (10 s segment) of one video, in time order: a video's activity log (reached from the video, not by a filter over every segment).
// params: participant, video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end, s.summary AS summary,
       s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
ORDER BY s.turn
