"""Console screens and dialogs, one per file."""
