// description: Activity records (10 s segments) by id, as the retrieval tools return them.
// params: participant, ids
MATCH (s:Segment)
WHERE s.participant = $participant AND s.id IN $ids
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end, s.summary AS summary,
       s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
