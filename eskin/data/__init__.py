"""Datasets: schema, ingest of raw logs, import of external files."""
