"""Benchmarks that print their figures (`memora perf ...`; not timed tests), one module a subject:
`build` (where a build's time goes), `video` (decoding and the video build), `model` (the evaluation
and a video build against a loopback model server), `ray` (Ray's overhead), `scale` (10 to 1,000
hours of one person), `startup` (one-shot commands as new processes), `tools` (tool latency and
recall), `encoders` (the query encoders side by side), `serve` (`memora serve` over HTTP), `verify`
(what the integrity checks add to opening a bank)."""
