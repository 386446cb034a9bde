// description: (the baselines' load, whole; public: baseline_segments, a video at a time) Every 10 s turn of a participant in chronological order (the baselines' activity records).
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end,
       s.summary AS summary, s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
ORDER BY video, turn
