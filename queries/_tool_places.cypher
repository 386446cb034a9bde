// description: The places (environment memory) of a participant.
// params: participant
MATCH (p:Place)
WHERE p.participant = $participant
RETURN p.id AS id, p.location_id AS location_id, p.name AS name, p.zones AS zones, p.features AS features,
       p.first_seen AS first_seen, p.first_video AS first_video, p.last_seen AS last_seen, p.last_video AS last_video,
       p.turn_count AS turn_count
ORDER BY id
