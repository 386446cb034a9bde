// description: A remembered moment that continues its video: as _live_add_moment (its places' sightings set through their IN_PLACE rows), plus the NEXT edge from the video's previous segment (none written when it is missing: 0 rows). Returns the IN_PLACE edges written.
// params: participant, video, duration, id, turn, t_start, t_end, summary, narrative, action_breakdown, working_summary, location, n_actions, n_objects, emb, key, result, at, rows, prev
// mode: write
MATCH (v:Video {id: $video}), (a:Segment {id: $prev})
WHERE v.participant = $participant AND a.participant = $participant
SET v.duration = $duration, v.n_turns = $turn + 1, v.n_actions = coalesce(v.n_actions, 0) + $n_actions
CREATE (v)-[:HAS_SEGMENT]->(s:Segment {id: $id, participant: $participant, video: $video, turn: $turn, t_start: $t_start, t_end: $t_end, summary: $summary, narrative: $narrative, action_breakdown: $action_breakdown, working_summary: $working_summary, location: $location, n_actions: $n_actions, n_objects: $n_objects, emb: $emb}),
       (:Remembered {id: $key, participant: $participant, video: $video, t: $t_start, segment: $id, result: $result, at: $at}),
       (a)-[:NEXT]->(s)
WITH s
UNWIND $rows AS r
MATCH (p:Place {id: r.to})
WHERE p.participant = $participant
CREATE (s)-[:IN_PLACE {op: r.op, is_primary: r.is_primary, zones: r.zones}]->(p)
SET p.zones = r.place_zones, p.features = r.features, p.last_seen = r.last_seen, p.last_video = r.last_video,
    p.turn_count = r.turn_count
RETURN count(*) AS n
