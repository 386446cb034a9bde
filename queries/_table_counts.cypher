// description: Rows per table of the whole database (integrity records and `memora verify`), and per node table the rows of any other participant.
// params: participant
// scope: database
MATCH (n)
RETURN label(n) AS table_name, count(*) AS rows, count(CASE WHEN n.participant <> $participant THEN 1 END) AS other_participant
UNION ALL
MATCH ()-[r]->()
RETURN label(r) AS table_name, count(*) AS rows, 0 AS other_participant
