"""Write a program to files in any export format (RAPID as one ``.mod`` per module plus a ``.pgf``)."""
from __future__ import annotations

from pathlib import Path
from typing import Any, TextIO

import numpy as np

from fabric.motion.program import Program
from fabric.planning.post.csv import RowTimes, write_csv
from fabric.planning.post.krl import write_krl
from fabric.planning.post.names import program_name
from fabric.planning.post.rapid import RapidOptions, write_rapid
from fabric.planning.post.urscript import write_urscript
from fabric.wire.errors import ValidationError

__all__ = ["export_program", "write_export", "FORMATS"]

FORMATS = ("rapid", "krl", "urscript", "csv")


def export_program(program: Program, fmt: str, path: str | Path, *, tool_T: np.ndarray | None = None,
                   t_end_s: np.ndarray | RowTimes | None = None, rapid: RapidOptions | None = None,
                   name: str = "am_print") -> list[Path]:
    """Export ``program`` as ``fmt`` (one of :data:`FORMATS`); returns the files written.

    ``rapid`` and ``krl`` write into the directory ``path`` (created if needed):
    RAPID one ``<module>.mod`` per module and ``<name>.pgf`` listing them; KRL
    ``<name>.src`` and ``<name>.dat``. ``urscript`` and ``csv`` write the file ``path``.
    ``name`` is made valid for every controller language first (:func:`program_name`).
    """
    name = program_name(name)
    if fmt not in FORMATS:
        raise ValidationError(f"unknown export format {fmt!r} (one of {', '.join(FORMATS)})", field="format",
                              value=fmt)
    path = Path(path)
    if fmt in ("rapid", "krl"):
        path.mkdir(parents=True, exist_ok=True)
    if fmt == "rapid":
        files: list[Path] = []
        streams = []

        def sink(module: str):
            f = open(path / f"{module}.mod", "w", encoding="latin-1", newline="\n")  # noqa: SIM115  (closed below)
            streams.append(f)
            files.append(path / f"{module}.mod")
            return f

        try:
            exp = write_rapid(program, sink, tool_T=tool_T, options=rapid)
        finally:
            for f in streams:
                f.close()
        pgf = path / f"{name}.pgf"
        mods = "\n".join(f"  <Module>{m}.mod</Module>" for m in exp.modules)
        pgf.write_text(f'<?xml version="1.0" encoding="ISO-8859-1" ?>\n<Program>\n{mods}\n</Program>\n')
        return [pgf, *files]
    if fmt == "krl":
        src, dat = path / f"{name}.src", path / f"{name}.dat"
        with open(src, "w", newline="\n") as fs, open(dat, "w", newline="\n") as fd:
            write_krl(program, fs, fd, name=name, tool_T=tool_T)
        return [src, dat]
    with open(path, "w", newline="\n") as f:
        if fmt == "urscript":
            write_urscript(program, f, name=name, tool_T=tool_T)
        else:
            write_csv(program, f, t_end_s)
    return [path]


def write_export(program: Program, fmt: str, out: TextIO, cell: Any = None, *, module_targets: int = 5000,
                 t_end_s: np.ndarray | RowTimes | None = None, name: str = "am_print") -> None:
    """Export ``program`` as ``fmt`` into one text stream (the TCP from ``cell.robot.tool_T`` if given).

    RAPID writes its modules one after another (main first, print modules of at
    most ``module_targets`` targets); KRL writes a self-contained ``.src`` with
    the frames inline. ``name`` is made valid for every controller language first (:func:`program_name`).
    """
    name = program_name(name)
    if fmt not in FORMATS:
        raise ValidationError(f"unknown export format {fmt!r} (one of {', '.join(FORMATS)})", field="format",
                              value=fmt)
    tool_T = None if cell is None else np.asarray(cell.robot.tool_T, dtype=float)
    if fmt == "rapid":
        write_rapid(program, out, tool_T=tool_T, options=RapidOptions(targets_per_module=module_targets))
    elif fmt == "krl":
        write_krl(program, out, None, name=name, tool_T=tool_T)
    elif fmt == "urscript":
        write_urscript(program, out, name=name, tool_T=tool_T)
    else:
        write_csv(program, out, t_end_s)
