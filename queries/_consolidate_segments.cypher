// description: A participant's activity log for offline consolidation: every segment, in time order.
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end,
       s.summary AS summary, s.location AS location
ORDER BY s.video, s.turn
