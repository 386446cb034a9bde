// description: (the baselines' load, whole; public: baseline_state_events, a video at a time) Every object observation of a participant with its object's name, in time order (baseline state records).
// params: participant
MATCH (e:Entity)-[:HAS_STATE]->(x:StateEvent)
WHERE e.participant = $participant
RETURN x.id AS id, e.id AS entity, e.name AS name, e.color AS color, e.material AS material, x.video AS video,
       x.turn AS turn, x.t AS t, x.state AS state, x.location AS location, x.prev_state AS prev_state,
       x.prev_location AS prev_location, x.action AS action, x.narration AS narration, x.op AS op
ORDER BY video, t, x.ord
