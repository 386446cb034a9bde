// description: One existing entity's changes from a remembered moment (the columns _entity_update writes), its id bound as a scalar so Kùzu looks it up in the primary-key index. Returns the entities written (1, or 0 when it is missing).
// params: participant, id, status, merged_into, state, location, held_by, color, material, size, last_seen, last_video, last_turn, n_observations
// mode: write
MATCH (e:Entity {id: $id})
WHERE e.participant = $participant
SET e.status = $status, e.merged_into = $merged_into, e.state = $state, e.location = $location,
    e.held_by = $held_by, e.color = $color, e.material = $material, e.size = $size,
    e.last_seen = $last_seen, e.last_video = $last_video, e.last_turn = $last_turn,
    e.n_observations = $n_observations
RETURN count(*) AS n
