// The four MEMORA stores as typed tables, one Kùzu database per participant.
// Every node carries `participant` so that queries stay scoped even if banks are merged.
// Embeddings (FLOAT[384], all-MiniLM-L6-v2) sit on nodes that are never SET after the build
// writes them, because Kùzu cannot SET a column that has a vector index.

// Activity memory
CREATE NODE TABLE Participant(id STRING PRIMARY KEY, participant STRING);
CREATE NODE TABLE Video(id STRING PRIMARY KEY, participant STRING, duration DOUBLE, n_turns INT64, n_actions INT64, mode STRING, built_at TIMESTAMP, build_seconds DOUBLE);
CREATE NODE TABLE Segment(id STRING PRIMARY KEY, participant STRING, video STRING, turn INT64, t_start DOUBLE, t_end DOUBLE, summary STRING, narrative STRING, action_breakdown STRING, working_summary STRING, location STRING, n_actions INT64, n_objects INT64, emb FLOAT[384]);

// Environment memory: merged by stable location id; its update history is the IN_PLACE edges.
CREATE NODE TABLE Place(id STRING PRIMARY KEY, participant STRING, location_id STRING, name STRING, zones STRING[], features STRING[], first_seen DOUBLE, first_video STRING, last_seen DOUBLE, last_video STRING, turn_count INT64, emb FLOAT[384]);

// Entity memory: one record per object; every observation is an immutable StateEvent.
CREATE NODE TABLE Entity(id STRING PRIMARY KEY, participant STRING, object_id STRING, kind STRING, name STRING, category STRING, color STRING, material STRING, size STRING, is_fixture BOOLEAN, status STRING, merged_into STRING, state STRING, location STRING, held_by STRING, first_seen DOUBLE, first_video STRING, first_turn INT64, last_seen DOUBLE, last_video STRING, last_turn INT64, n_observations INT64, emb FLOAT[384]);
CREATE NODE TABLE StateEvent(id STRING PRIMARY KEY, participant STRING, entity STRING, video STRING, turn INT64, t DOUBLE, ord INT64, state STRING, location STRING, prev_state STRING, prev_location STRING, zone STRING, held_by STRING, relative_to STRING, relation STRING, action STRING, narration STRING, op STRING);

// Editor log: every decision with its reason.
CREATE NODE TABLE EditOp(id STRING PRIMARY KEY, participant STRING, video STRING, turn INT64, t DOUBLE, op STRING, entity STRING, reason STRING, changes STRING, policy STRING);

// Inferred knowledge (written by offline consolidation).
CREATE NODE TABLE Routine(id STRING PRIMARY KEY, participant STRING, goal STRING, activity_type STRING, canonical_steps STRING[], key_objects STRING[], supporting_episodes STRING[], source_videos STRING[], count INT64, confidence DOUBLE, retrieval_text STRING, emb FLOAT[384]);
CREATE NODE TABLE Preference(id STRING PRIMARY KEY, participant STRING, subtype STRING, statement STRING, keywords STRING[], objects STRING[], context STRING, supporting_episodes STRING[], source_videos STRING[], count INT64, confidence DOUBLE, retrieval_text STRING, emb FLOAT[384]);

CREATE REL TABLE HAS_VIDEO(FROM Participant TO Video);
CREATE REL TABLE HAS_SEGMENT(FROM Video TO Segment);
CREATE REL TABLE NEXT(FROM Segment TO Segment);
CREATE REL TABLE IN_PLACE(FROM Segment TO Place, op STRING, is_primary BOOLEAN, zones STRING[]);
CREATE REL TABLE SPATIAL(FROM Place TO Place, relation STRING, video STRING, turn INT64);
CREATE REL TABLE HAS_STATE(FROM Entity TO StateEvent, ord INT64);
CREATE REL TABLE OBSERVED_IN(FROM StateEvent TO Segment);
CREATE REL TABLE AT(FROM StateEvent TO Place);
CREATE REL TABLE LOCATED_AT(FROM Entity TO Place);
CREATE REL TABLE EDITED(FROM EditOp TO Entity);
CREATE REL TABLE MERGED_INTO(FROM Entity TO Entity, video STRING, turn INT64);
CREATE REL TABLE SUPPORTED_BY(FROM Routine TO Segment, FROM Preference TO Segment);
CREATE REL TABLE USES(FROM Routine TO Entity);
CREATE REL TABLE ABOUT(FROM Preference TO Entity);
