// Model calls (perception, editor, ...) of video builds: one row per call, failed ones included,
// written with the video's checkpoint. Cost and latency per segment and per role come from here.
// `turn` is -1 and `segment` empty for calls that belong to no segment.
CREATE NODE TABLE ModelCall(id STRING PRIMARY KEY, participant STRING, video STRING, turn INT64, segment STRING, role STRING, backend STRING, model STRING, prompt_hash STRING, prompt_version STRING, tokens_in INT64, tokens_out INT64, latency_s DOUBLE, retries INT64, repairs INT64, ok BOOLEAN, error STRING, started_at TIMESTAMP);
