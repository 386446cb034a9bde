// description: The table that records which schema files a database has applied (created before any of them).
// mode: write
// scope: database
CREATE NODE TABLE IF NOT EXISTS SchemaMigration(id STRING PRIMARY KEY, checksum STRING, applied_at TIMESTAMP)
