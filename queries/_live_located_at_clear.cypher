// description: Drop one entity's current-location edge before a remembered moment moves it, its id bound as a scalar so Kùzu looks it up in the primary-key index (through UNWIND, _located_at_clear scans every entity: 11.8 ms of CPU at 1,000 h).
// params: participant, id
// mode: write
MATCH (e:Entity {id: $id})-[l:LOCATED_AT]->(:Place)
WHERE e.participant = $participant
DELETE l
