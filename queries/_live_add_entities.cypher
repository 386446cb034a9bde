// description: Entities the editor added for a remembered moment.
// params: participant, rows
// mode: write
UNWIND $rows AS r
CREATE (:Entity {id: r.id, participant: $participant, object_id: r.object_id, kind: r.kind, name: r.name, category: r.category, color: r.color, material: r.material, size: r.size, is_fixture: r.is_fixture, status: r.status, merged_into: r.merged_into, state: r.state, location: r.location, held_by: r.held_by, first_seen: r.first_seen, first_video: r.first_video, first_turn: r.first_turn, last_seen: r.last_seen, last_video: r.last_video, last_turn: r.last_turn, n_observations: r.n_observations, emb: r.emb})
RETURN count(*) AS n
