"""Durable state of a cell: SQLite stores (jobs, queue, events, checkpoints) and content-addressed artifacts."""
