"""Run outputs: column schemas defined once (schema), the runner's per-step recording callback
(recorder), chunked Parquet writers (writer) and reading a run folder, finished or killed (reader)."""
