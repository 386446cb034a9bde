// description: One activity record (10 s segment) by its id, looked up by key: the tools call it once per segment they return (a filter or an UNWIND over ids reads every segment, which grows with the hours).
// params: participant, id
MATCH (s:Segment {id: $id})
WHERE s.participant = $participant
RETURN s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end, s.summary AS summary,
       s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
