// description: Every activity record (10 s segment) as _tool_segment returns one, for the rows kept with the persisted tool stores (retrieve/rows.py).
// params: participant
MATCH (s:Segment)
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end, s.summary AS summary,
       s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
