// description: The places of a participant's environment memory (baseline environment records).
// params: participant
// example: memora run BANK baseline_places -p participant P01
MATCH (p:Place)
WHERE p.participant = $participant
RETURN p.id AS id, p.location_id AS location_id, p.name AS name, p.zones AS zones, p.features AS features,
       p.first_seen AS first_seen, p.first_video AS first_video, p.turn_count AS turn_count
ORDER BY location_id
