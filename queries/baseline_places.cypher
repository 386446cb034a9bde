// description: The places of a participant's environment memory (baseline environment records) (at most 1000 rows).
// params: participant
// example: memora run BANK baseline_places -p participant P01
// bound: limit 1000
MATCH (p:Place)
WHERE p.participant = $participant
RETURN p.id AS id, p.location_id AS location_id, p.name AS name, p.zones AS zones, p.features AS features,
       p.first_seen AS first_seen, p.first_video AS first_video, p.turn_count AS turn_count
ORDER BY location_id
LIMIT 1000
