import sys; sys.argv = ["x", "http://127.0.0.1:18431", "/work/wt/realmodel/notes/probe/default_format"]
exec(open("probe.py").read())
M = json.loads(urllib.request.urlopen("http://127.0.0.1:18431/v1/models").read())["data"][0]["id"]
ex("models", "GET", "/v1/models")
ex("chat_plain", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Name three kitchen objects."}], "temperature": 0, "max_tokens": 64})
ex("chat_other_model_name", "POST", "/v1/chat/completions", {"model": "Qwen/Qwen3.6-35B-A3B", "messages": [{"role": "user", "content": "Say hi."}], "temperature": 0, "max_tokens": 16})
ex("chat_no_model", "POST", "/v1/chat/completions", {"messages": [{"role": "user", "content": "Say hi."}], "temperature": 0, "max_tokens": 16})
tools = [{"type": "function", "function": {"name": "search_activities", "description": "Search the person's past activities.", "parameters": {"type": "object", "properties": {"query": {"type": "string"}}, "required": ["query"]}}}]
ex("chat_tools_auto", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "system", "content": "Use the tools to answer."}, {"role": "user", "content": "Where does the person keep the plate? Search their activities."}], "tools": tools, "temperature": 0, "max_tokens": 128})
ex("chat_tools_required", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Where is the plate?"}], "tools": tools, "tool_choice": "required", "temperature": 0, "max_tokens": 128})
ex("chat_tools_named", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Where is the plate?"}], "tools": tools, "tool_choice": {"type": "function", "function": {"name": "search_activities"}}, "temperature": 0, "max_tokens": 128})
ex("json_object", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Give a JSON object with keys name and place for a plate."}], "response_format": {"type": "json_object"}, "temperature": 0, "max_tokens": 128})
schema = {"type": "object", "properties": {"object": {"type": "string"}, "place": {"type": "string", "enum": ["sink", "cupboard", "fridge"]}, "count": {"type": "integer"}}, "required": ["object", "place", "count"], "additionalProperties": False}
ex("json_schema", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Where is the plate kept?"}], "response_format": {"type": "json_schema", "json_schema": {"name": "Where", "schema": schema}}, "temperature": 0, "max_tokens": 128})
ex("json_schema_strict", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Where is the plate kept?"}], "response_format": {"type": "json_schema", "json_schema": {"name": "Where", "schema": schema, "strict": True}}, "temperature": 0, "max_tokens": 128})
ex("json_schema_maxtokens_small", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Describe the plate in detail."}], "response_format": {"type": "json_schema", "json_schema": {"name": "D", "schema": {"type": "object", "properties": {"description": {"type": "string"}}, "required": ["description"]}}}, "temperature": 0, "max_tokens": 12})
ex("bad_key", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "hi"}], "max_tokens": 4}, headers={"Authorization": "Bearer wrong"})
long = "the person took the plate from the cupboard and washed it in the sink. " * 200
ex("over_ctx", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": long}], "temperature": 0, "max_tokens": 64})
ex("over_ctx_with_max_tokens", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "the plate " * 900}], "temperature": 0, "max_tokens": 2048})
ex("tool_role_message", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": "Where is the plate?"}, {"role": "assistant", "content": "", "tool_calls": [{"id": "call_1", "type": "function", "function": {"name": "search_activities", "arguments": "{\"query\": \"plate\"}"}}]}, {"role": "tool", "tool_call_id": "call_1", "name": "search_activities", "content": "[{\"text\": \"put plate in cupboard\"}]"}], "tools": tools, "temperature": 0, "max_tokens": 64})
ex("content_parts", "POST", "/v1/chat/completions", {"model": M, "messages": [{"role": "user", "content": [{"type": "text", "text": "Say hi."}]}], "temperature": 0, "max_tokens": 16})
ex("not_json_body", "POST", "/v1/chat/completions", None)
ex("unknown_path", "GET", "/v1/nothing")
