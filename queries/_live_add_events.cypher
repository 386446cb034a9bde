// description: The state events of a remembered moment, each on its entity, observed in the moment's segment (bound as a scalar: looked up in the primary-key index, not scanned), at its place.
// params: participant, segment, rows
// mode: write
MATCH (s:Segment {id: $segment})
WHERE s.participant = $participant
UNWIND $rows AS r
MATCH (e:Entity {id: r.entity}), (p:Place {id: r.place})
WHERE e.participant = $participant AND p.participant = $participant
CREATE (e)-[:HAS_STATE {ord: r.ord}]->(x:StateEvent {id: r.id, participant: $participant, entity: r.entity, video: r.video, turn: r.turn, t: r.t, ord: r.ord, state: r.state, location: r.location, prev_state: r.prev_state, prev_location: r.prev_location, zone: r.zone, held_by: r.held_by, relative_to: r.relative_to, relation: r.relation, action: r.action, narration: r.narration, op: r.op})-[:OBSERVED_IN]->(s), (x)-[:AT]->(p)
RETURN count(*) AS n
