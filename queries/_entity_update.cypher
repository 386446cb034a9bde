// description: Write the editor's changes to existing entities (one row per changed entity).
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (e:Entity {id: r.id})
WHERE e.participant = $participant
SET e.status = r.status, e.merged_into = r.merged_into, e.state = r.state, e.location = r.location,
    e.held_by = r.held_by, e.color = r.color, e.material = r.material, e.size = r.size,
    e.last_seen = r.last_seen, e.last_video = r.last_video, e.last_turn = r.last_turn,
    e.n_observations = r.n_observations
