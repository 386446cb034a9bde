// description: The active object records of a participant (one per observation in a raw bank, one per object when edited) (at most 1000 rows).
// params: participant
// example: memora run BANK baseline_entities -p participant P01
// bound: limit 1000
MATCH (e:Entity)
WHERE e.participant = $participant AND e.status = 'active'
RETURN e.id AS id, e.object_id AS object_id, e.name AS name, e.category AS category, e.color AS color,
       e.material AS material, e.size AS size, e.is_fixture AS is_fixture, e.state AS state, e.location AS location,
       e.first_seen AS first_seen, e.first_video AS first_video, e.first_turn AS first_turn, e.last_seen AS last_seen,
       e.last_video AS last_video, e.last_turn AS last_turn, e.n_observations AS n_observations
ORDER BY first_video, first_seen, id
LIMIT 1000
