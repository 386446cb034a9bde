// description: Places first seen in a remembered moment.
// params: participant, rows
// mode: write
UNWIND $rows AS r
CREATE (:Place {id: r.id, participant: $participant, location_id: r.location_id, name: r.name, zones: r.zones, features: r.features, first_seen: r.first_seen, first_video: r.first_video, last_seen: r.last_seen, last_video: r.last_video, turn_count: r.turn_count, emb: r.emb})
RETURN count(*) AS n
