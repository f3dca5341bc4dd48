"""Post-processors: a planned :class:`~fabric.motion.program.Program` -> controller code or CSV."""
from fabric.planning.post.csv import CSV_COLUMNS, write_csv
from fabric.planning.post.files import FORMATS, export_program, write_export
from fabric.planning.post.krl import write_krl
from fabric.planning.post.rapid import RapidExport, RapidOptions, write_rapid
from fabric.planning.post.urscript import write_urscript

__all__ = ["write_rapid", "RapidOptions", "RapidExport", "write_krl", "write_urscript", "write_csv",
           "CSV_COLUMNS", "export_program", "write_export", "FORMATS"]
