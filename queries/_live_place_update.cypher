// description: One existing place's merged zones and sightings from a remembered moment, with its new embedding (its text changed), the id bound as a scalar (a primary-key lookup). Returns the places written (1, or 0 when it is missing).
// params: participant, id, zones, features, last_seen, last_video, turn_count, emb
// mode: write
MATCH (p:Place {id: $id})
WHERE p.participant = $participant
SET p.zones = $zones, p.features = $features, p.last_seen = $last_seen, p.last_video = $last_video,
    p.turn_count = $turn_count, p.emb = $emb
RETURN count(*) AS n
