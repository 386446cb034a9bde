// description: One state event of a remembered moment, on its entity, observed in the moment's segment, at its place: every id bound as a scalar (primary-key lookups, no scan). Returns the events written (1, or 0 when an endpoint is missing).
// params: participant, segment, entity, place, id, video, turn, t, ord, state, location, prev_state, prev_location, zone, held_by, relative_to, relation, action, narration, op
// mode: write
MATCH (s:Segment {id: $segment}), (e:Entity {id: $entity}), (p:Place {id: $place})
WHERE s.participant = $participant AND e.participant = $participant AND p.participant = $participant
CREATE (e)-[:HAS_STATE {ord: $ord}]->(x:StateEvent {id: $id, participant: $participant, entity: $entity, video: $video, turn: $turn, t: $t, ord: $ord, state: $state, location: $location, prev_state: $prev_state, prev_location: $prev_location, zone: $zone, held_by: $held_by, relative_to: $relative_to, relation: $relation, action: $action, narration: $narration, op: $op})-[:OBSERVED_IN]->(s), (x)-[:AT]->(p)
RETURN count(*) AS n
