// description: Every row of `object_registry` (for the code that needs them all; not offered by servers). The object registry as planning tasks ground nouns against it: id, name, colour, material, where it is.
// params: participant
MATCH (e:Entity)
WHERE e.participant = $participant AND e.status = 'active' AND NOT e.is_fixture
OPTIONAL MATCH (e)-[:LOCATED_AT]->(p:Place)
RETURN e.object_id AS memory_id, e.name AS memory_name, e.color AS color, e.material AS material,
       coalesce(p.name, e.location) AS location, e.n_observations AS observations
ORDER BY observations DESC, memory_id
