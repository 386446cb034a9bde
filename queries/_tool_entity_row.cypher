// description: One entity as _tool_entities returns it, with its vector (a server's reader takes in an entity a remembered moment added or changed; the id bound in the pattern: a primary-key lookup).
// params: participant, id
MATCH (e:Entity {id: $id})
WHERE e.participant = $participant
RETURN e.id AS id, e.object_id AS object_id, e.kind AS kind, e.name AS name, e.category AS category, e.color AS color,
       e.material AS material, e.size AS size, e.is_fixture AS is_fixture, e.status AS status,
       e.merged_into AS merged_into, e.state AS state, e.location AS location, e.held_by AS held_by,
       e.first_seen AS first_seen, e.first_video AS first_video, e.first_turn AS first_turn, e.last_seen AS last_seen,
       e.last_video AS last_video, e.last_turn AS last_turn, e.n_observations AS n_observations, e.emb AS emb
