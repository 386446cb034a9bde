// description: Every place of a participant (the whole node), as environment memory reloads it to resume a build.
// params: participant
MATCH (p:Place)
WHERE p.participant = $participant
RETURN p AS place
ORDER BY p.location_id
