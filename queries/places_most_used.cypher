// description: The places a participant uses most, by the number of 10 s turns spent there (at most 100 rows).
// params: participant
// example: memora run BANK places_most_used -p participant P01
// bound: limit 100
MATCH (s:Segment)-[r:IN_PLACE]->(p:Place)
WHERE p.participant = $participant AND r.is_primary
WITH p, count(s) AS turns
RETURN p.location_id AS place, p.name AS name, turns, p.zones AS zones
ORDER BY turns DESC, place
LIMIT 100
