// description: The schema files applied to this database, with their checksums.
// scope: database
MATCH (m:SchemaMigration)
RETURN m.id AS file, m.checksum AS checksum, m.applied_at AS applied_at
ORDER BY file
