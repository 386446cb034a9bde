// description: The explorer's places (by location id), most used first.
// params: participant
MATCH (p:Place)
WHERE p.participant = $participant
RETURN p.location_id AS id, p.name AS name, p.zones AS zones, p.features AS features, p.turn_count AS turns,
       p.first_video AS first_video, p.last_video AS last_video
ORDER BY turns DESC, id
