// Live memory (`memora remember`, the MCP `remember` tool): one row per acknowledged remember,
// written in the transaction that writes its memory. `id` is the client's key (an explicit id,
// or the video and start time), so a retried call finds its first answer (`result`, the editor's
// operations as JSON) and writes nothing twice.
CREATE NODE TABLE Remembered(id STRING PRIMARY KEY, participant STRING, video STRING, t DOUBLE, segment STRING, result STRING, at TIMESTAMP);
