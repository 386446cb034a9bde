// description: One existing entity's edit in a remembered moment, in one statement: its changed columns (as _live_entity_update), the editor's operation on it (as _live_add_op) and its state event observed in the moment's segment at its place (as _live_add_event); every id bound as a scalar (primary-key lookups, no scan). Returns 1, or 0 when the entity, segment or place is missing.
// params: participant, id, status, merged_into, state, location, held_by, color, material, size, last_seen, last_video, last_turn, n_observations, segment, place, op_id, op_video, op_turn, op_t, op, reason, changes, policy, ev_id, ev_video, ev_turn, ev_t, ord, ev_state, ev_location, prev_state, prev_location, zone, ev_held_by, relative_to, relation, action, narration, ev_op
// mode: write
MATCH (e:Entity {id: $id}), (s:Segment {id: $segment}), (p:Place {id: $place})
WHERE e.participant = $participant AND s.participant = $participant AND p.participant = $participant
SET e.status = $status, e.merged_into = $merged_into, e.state = $state, e.location = $location,
    e.held_by = $held_by, e.color = $color, e.material = $material, e.size = $size,
    e.last_seen = $last_seen, e.last_video = $last_video, e.last_turn = $last_turn,
    e.n_observations = $n_observations
CREATE (:EditOp {id: $op_id, participant: $participant, video: $op_video, turn: $op_turn, t: $op_t, op: $op, entity: $id, reason: $reason, changes: $changes, policy: $policy})-[:EDITED]->(e),
       (e)-[:HAS_STATE {ord: $ord}]->(x:StateEvent {id: $ev_id, participant: $participant, entity: $id, video: $ev_video, turn: $ev_turn, t: $ev_t, ord: $ord, state: $ev_state, location: $ev_location, prev_state: $prev_state, prev_location: $prev_location, zone: $zone, held_by: $ev_held_by, relative_to: $relative_to, relation: $relation, action: $action, narration: $narration, op: $ev_op})-[:OBSERVED_IN]->(s),
       (x)-[:AT]->(p)
RETURN count(*) AS n
