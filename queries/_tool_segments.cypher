// description: Activity records (10 s segments) by id, as the retrieval tools return them: each looked up by its key, so a call reads only the segments it returns (a filter over every segment grew with the hours).
// params: participant, ids
UNWIND $ids AS wanted
MATCH (s:Segment {id: wanted})
WHERE s.participant = $participant
RETURN DISTINCT s.id AS id, s.video AS video, s.turn AS turn, s.t_start AS t_start, s.t_end AS t_end, s.summary AS summary,
       s.narrative AS narrative, s.action_breakdown AS action_breakdown, s.location AS location
