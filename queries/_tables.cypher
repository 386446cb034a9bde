// description: The database's tables (catalog), node and relationship.
// scope: database
CALL show_tables() RETURN name, type
