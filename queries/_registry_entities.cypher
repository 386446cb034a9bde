// description: Every entity of a participant (the whole node: its columns are the schema's), as the editor reloads it to resume a build.
// params: participant
MATCH (e:Entity)
WHERE e.participant = $participant
RETURN e AS entity
ORDER BY e.id
