// description: Every video's state-history entries, as _tool_video_events returns one video's, for the rows kept with the persisted tool stores (retrieve/rows.py, which orders them: a fetch this large came back out of an ORDER BY).
// params: participant
MATCH (v:Video)-[:HAS_SEGMENT]->(:Segment)<-[:OBSERVED_IN]-(s:StateEvent)
WHERE v.participant = $participant AND s.participant = $participant
RETURN v.id AS video, s.id AS id, s.entity AS entity, s.turn AS turn, s.t AS t, s.ord AS ord, s.state AS state,
       s.location AS location, s.zone AS zone, s.held_by AS held_by, s.relative_to AS relative_to,
       s.relation AS relation, s.action AS action
