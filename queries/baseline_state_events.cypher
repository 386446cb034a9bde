// description: The object observations of one video, each with its object's name, in time order (the baseline state records, a video at a time: `videos` lists them).
// params: participant, video
// example: memora run BANK baseline_state_events -p participant P01 -p video P01_102
// bound: page video
MATCH (v:Video {id: $video})-[:HAS_SEGMENT]->(:Segment)<-[:OBSERVED_IN]-(x:StateEvent)<-[:HAS_STATE]-(e:Entity)
WHERE v.participant = $participant
RETURN x.id AS id, e.id AS entity, e.name AS name, e.color AS color, e.material AS material, x.video AS video,
       x.turn AS turn, x.t AS t, x.state AS state, x.location AS location, x.prev_state AS prev_state,
       x.prev_location AS prev_location, x.action AS action, x.narration AS narration, x.op AS op
ORDER BY t, x.ord, id
