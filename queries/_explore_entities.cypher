// description: The explorer's objects: every entity record (merged ones too), most observed first.
// params: participant
MATCH (e:Entity)
WHERE e.participant = $participant
RETURN e.id AS id, e.object_id AS object_id, e.name AS name, e.category AS category, e.color AS color,
       e.material AS material, e.status AS status, e.merged_into AS merged_into, e.state AS state,
       e.location AS location, e.held_by AS held_by, e.n_observations AS observations, e.first_video AS first_video,
       e.last_video AS last_video
ORDER BY observations DESC, id
