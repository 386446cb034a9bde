// description: Every state-history entry of one video in time order (for the state at a time t), reached from the video through its segments (each entry is OBSERVED_IN one segment of its video), not by a filter over every state entry.
// params: participant, video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(:Segment)<-[:OBSERVED_IN]-(s:StateEvent)
WHERE s.participant = $participant
RETURN s.id AS id, s.entity AS entity, s.turn AS turn, s.t AS t, s.ord AS ord, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action
ORDER BY t, ord
