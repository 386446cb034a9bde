// description: Record one schema file as applied, in the transaction that applied it ($applied_at: ISO 8601 text, UTC).
// params: id, checksum, applied_at
// mode: write
// scope: database
CREATE (m:SchemaMigration {id: $id, checksum: $checksum, applied_at: timestamp($applied_at)})
