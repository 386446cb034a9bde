// description: The entity registry: current state and location of every object, most observed first (at most 1000 rows).
// params: participant
// example: memora run BANK entities -p participant P01
// bound: limit 1000
MATCH (e:Entity)
WHERE e.participant = $participant AND e.status = 'active'
RETURN e.object_id AS object_id, e.name AS name, e.category AS category, e.state AS state,
       e.location AS location, e.n_observations AS observations, e.first_video AS first_video, e.last_video AS last_video
ORDER BY observations DESC, object_id
LIMIT 1000
