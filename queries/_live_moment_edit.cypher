// description: The common remembered moment in one statement: it continues its video (NEXT from the previous segment), happened in one place, and edited one existing entity. As _live_add_moment_next with its one IN_PLACE row bound as scalars (the place's merged zones, features and sightings set), then that entity's edit as _live_edit (its changed columns, the editor's operation, and its state event observed in the new segment at the entity's place) in a second CREATE (one CREATE clause holding all of it lost the state event in Kùzu 0.11.3: its row was not kept at commit). Every id bound as a scalar (primary-key lookups, no scan). Returns 1, or 0 when the video, the previous segment, a place or the entity is missing.
// params: participant, video, duration, id, turn, t_start, t_end, summary, narrative, action_breakdown, working_summary, location, n_actions, n_objects, emb, key, result, at, prev, place, in_op, is_primary, zones, place_zones, features, place_last_seen, place_last_video, turn_count, entity, status, merged_into, state, e_location, held_by, color, material, size, last_seen, last_video, last_turn, n_observations, ev_place, op_id, op_video, op_turn, op_t, op, reason, changes, policy, ev_id, ev_video, ev_turn, ev_t, ord, ev_state, ev_location, prev_state, prev_location, zone, ev_held_by, relative_to, relation, action, narration, ev_op
// mode: write
MATCH (v:Video {id: $video}), (a:Segment {id: $prev}), (p:Place {id: $place}), (e:Entity {id: $entity}), (q:Place {id: $ev_place})
WHERE v.participant = $participant AND a.participant = $participant AND p.participant = $participant
  AND e.participant = $participant AND q.participant = $participant
SET v.duration = $duration, v.n_turns = $turn + 1, v.n_actions = coalesce(v.n_actions, 0) + $n_actions,
    p.zones = $place_zones, p.features = $features, p.last_seen = $place_last_seen, p.last_video = $place_last_video,
    p.turn_count = $turn_count,
    e.status = $status, e.merged_into = $merged_into, e.state = $state, e.location = $e_location,
    e.held_by = $held_by, e.color = $color, e.material = $material, e.size = $size,
    e.last_seen = $last_seen, e.last_video = $last_video, e.last_turn = $last_turn,
    e.n_observations = $n_observations
CREATE (v)-[:HAS_SEGMENT]->(s:Segment {id: $id, participant: $participant, video: $video, turn: $turn, t_start: $t_start, t_end: $t_end, summary: $summary, narrative: $narrative, action_breakdown: $action_breakdown, working_summary: $working_summary, location: $location, n_actions: $n_actions, n_objects: $n_objects, emb: $emb}),
       (:Remembered {id: $key, participant: $participant, video: $video, t: $t_start, segment: $id, result: $result, at: $at}),
       (a)-[:NEXT]->(s),
       (s)-[:IN_PLACE {op: $in_op, is_primary: $is_primary, zones: $zones}]->(p)
WITH s, e, q
CREATE (:EditOp {id: $op_id, participant: $participant, video: $op_video, turn: $op_turn, t: $op_t, op: $op, entity: $entity, reason: $reason, changes: $changes, policy: $policy})-[:EDITED]->(e),
       (e)-[:HAS_STATE {ord: $ord}]->(x:StateEvent {id: $ev_id, participant: $participant, entity: $entity, video: $ev_video, turn: $ev_turn, t: $ev_t, ord: $ord, state: $ev_state, location: $ev_location, prev_state: $prev_state, prev_location: $prev_location, zone: $zone, held_by: $ev_held_by, relative_to: $relative_to, relation: $relation, action: $action, narration: $narration, op: $ev_op})-[:OBSERVED_IN]->(s),
       (x)-[:AT]->(q)
RETURN count(*) AS n
