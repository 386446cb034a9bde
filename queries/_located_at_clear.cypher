// description: Drop the current-location edges of entities whose location the build rewrites.
// params: participant, ids
// mode: write
UNWIND $ids AS id
MATCH (e:Entity {id: id})-[l:LOCATED_AT]->(:Place)
WHERE e.participant = $participant
DELETE l
