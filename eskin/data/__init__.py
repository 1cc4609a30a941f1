"""Datasets: scene plans, the raw log, ingest, import of other instruments' files, and the
dataset schema.

Public: :mod:`~eskin.data.plan` (what a scene records), :mod:`~eskin.data.rawlog` (the
append-only log), :func:`eskin.data.ingest.ingest_contents` (a raw log into a dataset),
:mod:`~eskin.data.importer`, and :mod:`~eskin.data.schema` (``read_dataset``,
``write_dataset``, ``contact_mask``)."""
