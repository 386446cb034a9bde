// description: The explorer's timeline: every 10 s segment with its primary place and what happened.
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t0, s.t_end AS t1, s.location AS place,
       s.summary AS summary, s.narrative AS narrative
ORDER BY video, turn
