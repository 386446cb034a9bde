// Inferred knowledge, provenance and structure (written by memora_graph.consolidate).
// source: which processor step produced the record (consolidation: storage / habit / workflow
// preferences and recurring action sequences; enrichment: routine skills and generated
// preferences). detail: a JSON object with the fields that differ per subtype (trigger and next
// action of a habit, the alternatives a tool preference beat, the episodes of a routine, counts
// per video), so every record can show why it exists.
ALTER TABLE Routine ADD source STRING DEFAULT '';
ALTER TABLE Routine ADD processor STRING DEFAULT '';
ALTER TABLE Routine ADD detail STRING DEFAULT '{}';
ALTER TABLE Preference ADD source STRING DEFAULT '';
ALTER TABLE Preference ADD processor STRING DEFAULT '';
ALTER TABLE Preference ADD evidence_summary STRING DEFAULT '';
ALTER TABLE Preference ADD detail STRING DEFAULT '{}';
