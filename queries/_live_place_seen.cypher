// description: One existing place seen again in a remembered moment whose text (name and zones) did not change: its zones, features and sightings, the embedding left as it is (the same text embeds to the same vector); the id bound as a scalar (a primary-key lookup). Returns the places written (1, or 0 when it is missing).
// params: participant, id, zones, features, last_seen, last_video, turn_count
// mode: write
MATCH (p:Place {id: $id})
WHERE p.participant = $participant
SET p.zones = $zones, p.features = $features, p.last_seen = $last_seen, p.last_video = $last_video,
    p.turn_count = $turn_count
RETURN count(*) AS n
