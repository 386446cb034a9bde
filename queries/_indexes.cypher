// description: The full-text and vector indexes the database has, with their tables.
// scope: database
CALL SHOW_INDEXES() RETURN index_name, table_name
