"""Run outputs: column schemas defined once (schema), the runner's per-step recording callback
(recorder), the writers: chunked Arrow streams finished into Parquet (writer) and reading a run folder, finished or killed (reader)."""
