"""The supervisor's file library commands: ``files``, ``file_add``, ``file_remove``, ``upload``, and what a
submission takes from the library (a ``JobSubmit`` with ``file_id``) or from an upload (``upload_id``: a large
file sent in pieces to ``supervisor/upload``), or gives to the library (every submitted file).

Every change runs as a step of the supervisor's writer, as changes of job records do.
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fabric import schemas as s
from fabric.printjobs.library import FileLibrary, check_size
from fabric.schemas.pipeline import source_of
from fabric.schemas.upload import MAX_SUBMIT_BYTES
from fabric.server.uploads import UploadStore
from fabric.store.artifacts import ArtifactStore
from fabric.store.library import LibraryStore
from fabric.wire.errors import FabricError, ValidationError

__all__ = ["LibraryCommands", "Submission"]

Step = Callable[[Callable[[], Any]], Any]


class Submission:
    """What a ``JobSubmit`` asks to print: the bytes, their name and kind, and its library entry."""

    def __init__(self, data: bytes, filename: str, source: str, file_id: str, upload_id: str = "") -> None:
        self.data, self.filename, self.source, self.file_id = data, filename, source, file_id
        self.upload_id = upload_id          # the upload it came from ("": none), removed once kept


class LibraryCommands:
    """The library of one supervisor (``step``: runs a function on the supervisor's writer)."""

    def __init__(self, data_dir: Path, artifacts: ArtifactStore, service: str, step: Step,
                 log: logging.Logger) -> None:
        self.library = FileLibrary(LibraryStore(data_dir / "library.sqlite"), artifacts, data_dir, service)
        self.uploads = UploadStore(data_dir / "uploads", MAX_SUBMIT_BYTES)    # large files to submit, in pieces
        self.step, self.log = step, log

    def on_upload(self, chunk: s.UploadChunk) -> s.UploadStatus:
        return self.uploads.put(chunk)

    def on_files(self, req: s.FilesQuery) -> s.FileList:
        return self.library.page(req)

    def on_file_add(self, req: s.FileAdd) -> s.LibraryFile:
        return self.step(lambda: self.library.add(req.data, req.name, req.source))

    def on_file_remove(self, req: s.FileQuery) -> s.Ack:
        entry = self.step(lambda: self.library.remove(req.file_id))
        return s.Ack(ok=True, message=f"removed {entry.name} ({entry.file_id}) from the library")

    def submission(self, req: s.JobSubmit) -> Submission:
        """The file a submission prints: its own bytes, an upload's or a library entry's (exactly one of them).
        Changes nothing (see :meth:`keep`), so that a submission refused after this leaves no trace."""
        given = [name for name, value in (("model", req.model), ("upload_id", req.upload_id),
                                          ("file_id", req.file_id)) if value]
        if len(given) > 1:
            raise ValidationError(f"give the file's bytes (model), an upload (upload_id) or a library file "
                                  f"(file_id), not {'both' if len(given) == 2 else 'all of'} {' and '.join(given)}",
                                  field=given[-1])
        if not given:
            raise ValidationError("the submitted file is empty: give its bytes (model), an upload (upload_id) or "
                                  "a library file (file_id)", field="model")
        if req.file_id:
            entry = self.library.get(req.file_id)
            if req.source and req.source != entry.source:
                raise ValidationError(f"library file {entry.file_id} is {entry.source}, not {req.source}",
                                      field="source")
            return Submission(self.library.data(entry), req.filename or entry.name, entry.source, entry.file_id)
        source = source_of(req.filename, req.source)
        if req.upload_id:
            data = self.uploads.path(req.upload_id).read_bytes()
            check_size(len(data), source, "upload_id")
            return Submission(data, req.filename, source, "", req.upload_id)
        check_size(len(req.model), source, "model")
        return Submission(req.model, req.filename, source, "")

    def keep(self, sub: Submission) -> Submission:
        """The submission's file in the library (entered now when it came as bytes or an upload, whose file
        then goes)."""
        if sub.file_id:
            return sub
        entry = self.step(lambda: self.library.add(sub.data, sub.filename, sub.source))
        if sub.upload_id:
            self.uploads.discard(sub.upload_id)
        return Submission(sub.data, sub.filename, sub.source, entry.file_id)

    def job_made(self, file_id: str, rec: s.JobRecord) -> None:
        """(Writer) A job was made from the library entry ``file_id``."""
        self.library.used(file_id, rec)

    def job_changed(self, rec: s.JobRecord) -> None:
        """(Writer) A record changed: the library shows its last job's state and plan. A library that cannot
        be written does not stop the job (it is logged)."""
        try:
            self.library.job_changed(rec)
        except FabricError as err:
            self.log.warning("library: could not note job %s: %s: %s", rec.job_id, err.code, err.message)

    def close(self) -> None:
        self.library.store.close()
