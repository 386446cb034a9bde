// description: The merged duplicates among a participant's narrated entities, with what each was merged into (consolidation resolves them).
// params: participant
MATCH (e:Entity)-[:HAS_STATE]->(s:StateEvent)-[:OBSERVED_IN]->(g:Segment)
WHERE s.participant = $participant AND s.action <> '' AND e.status = 'merged' AND e.merged_into <> ''
RETURN DISTINCT e.id AS entity, e.merged_into AS merged_into
