// description: Write merged zones and sightings to existing places.
// params: participant, rows
// mode: write
UNWIND $rows AS r
MATCH (p:Place {id: r.id})
WHERE p.participant = $participant
SET p.zones = r.zones, p.features = r.features, p.last_seen = r.last_seen, p.last_video = r.last_video,
    p.turn_count = r.turn_count, p.emb = r.emb
