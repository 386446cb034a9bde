// description: Every activity record of one participant with its narrated steps, in time order (the open-question reader's log).
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.action_breakdown AS action_breakdown
ORDER BY s.video, s.turn
