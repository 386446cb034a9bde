// description: Every state-history entry of one video in time order (for the state at a time t).
// params: participant, video
MATCH (s:StateEvent)
WHERE s.participant = $participant AND s.video = $video
RETURN s.id AS id, s.entity AS entity, s.turn AS turn, s.t AS t, s.ord AS ord, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action
ORDER BY t, ord
