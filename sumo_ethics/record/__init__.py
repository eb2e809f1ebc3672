"""Run outputs: column schemas defined once, Parquet writers, the summary."""
