// description: Every entity of a participant as columns (each of the schema's, the embedding last), as the editor reloads it to resume a build or a live writer; in no order (the caller sorts by id: Kùzu's ORDER BY over the embeddings cost more than the read).
// params: participant
MATCH (e:Entity)
WHERE e.participant = $participant
RETURN e.id AS id, e.participant AS participant, e.object_id AS object_id, e.kind AS kind, e.name AS name,
       e.category AS category, e.color AS color, e.material AS material, e.size AS size, e.is_fixture AS is_fixture,
       e.status AS status, e.merged_into AS merged_into, e.state AS state, e.location AS location,
       e.held_by AS held_by, e.first_seen AS first_seen, e.first_video AS first_video, e.first_turn AS first_turn,
       e.last_seen AS last_seen, e.last_video AS last_video, e.last_turn AS last_turn,
       e.n_observations AS n_observations, e.emb AS emb
