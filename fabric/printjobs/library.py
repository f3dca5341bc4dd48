"""The file library's rules: what entering a file, making a job from it, and a job's progress change.

The supervisor calls these from its writer (one thread changes the library, as it changes the job
records); the bytes go to its content-addressed artifact store, pinned for as long as an entry keeps them.
"""
from __future__ import annotations

import time
from pathlib import Path

from fabric import schemas as s
from fabric.programs import content_id
from fabric.schemas.pipeline import source_of
from fabric.schemas.upload import MAX_GCODE_BYTES, MAX_MODEL_BYTES, MIB
from fabric.server.disk import require_room
from fabric.store.artifacts import ArtifactStore
from fabric.store.library import LibraryStore, entry_id
from fabric.wire.errors import NotFound, ValidationError

__all__ = ["FileLibrary", "MODEL_MEDIA", "MAX_BYTES", "check_size"]

MODEL_MEDIA = {"model": "application/octet-stream", "gcode": "text/x-gcode"}
MAX_BYTES = {"model": MAX_MODEL_BYTES, "gcode": MAX_GCODE_BYTES}    # the most the slicer and the planner take


def check_size(size: int, source: str, field: str) -> None:
    """A file of ``source`` (model or gcode) no larger than the service that takes it accepts: a ValidationError
    naming ``field`` otherwise (a larger model would fail at the slicer, after being queued)."""
    limit = MAX_BYTES[source]
    if size > limit:
        raise ValidationError(f"the {source} is {size / MIB:,.1f} MiB, more than the {limit / MIB:,.0f} MiB the "
                              f"{'slicer' if source == 'model' else 'planner'} takes", field=field, value=size,
                              limit=limit)


def _pin_owner(file_id: str) -> str:
    return f"library:{file_id}"


class FileLibrary:
    """Files kept to print again (see :mod:`fabric.schemas.library`)."""

    def __init__(self, store: LibraryStore, artifacts: ArtifactStore, data_dir: Path, service: str) -> None:
        self.store, self.artifacts, self.data_dir, self.service = store, artifacts, data_dir, service

    def add(self, data: bytes, name: str, source: str = "") -> s.LibraryFile:
        """Keep ``data`` under ``name`` (an entry already there is returned as it is)."""
        if not data:
            raise ValidationError("the file is empty", field="data")
        name = name.replace("\\", "/").rsplit("/", 1)[-1].strip()      # a path's last part: the file's name
        if not name:
            raise ValidationError("a library file needs a file name", field="name")
        kind = source_of(name, source)
        check_size(len(data), kind, "data")
        cid = content_id(data)
        fid = entry_id(cid, name)
        known = self.store.find(fid)
        if known is not None:
            return known
        require_room(self.data_dir, len(data), self.service, "the file")
        self.artifacts.put(s.Artifact(artifact_id=cid, name=name, media_type=MODEL_MEDIA[kind], data=data))
        self.artifacts.pin(cid, _pin_owner(fid))
        entry = s.LibraryFile(file_id=fid, name=name, source=kind, content_id=cid, size_bytes=len(data),
                              added_s=time.time())
        self.store.put(entry)
        return entry

    def get(self, file_id: str) -> s.LibraryFile:
        return self.store.get(file_id)

    def data(self, entry: s.LibraryFile) -> bytes:
        """The bytes of ``entry`` (NotFound, saying so, when the store lost them)."""
        try:
            return self.artifacts.get(entry.content_id).data
        except NotFound:
            raise NotFound(f"library file {entry.file_id} ({entry.name}): its bytes are no longer kept (the "
                           f"supervisor's data folder lost them); add the file again", file_id=entry.file_id) from None

    def used(self, file_id: str, rec: s.JobRecord) -> s.LibraryFile:
        """A job ``rec`` was made from the entry: count it, and keep its settings for "print again"."""
        entry = self.store.get(file_id)
        entry.jobs += 1
        entry.used_s = rec.created_s or time.time()
        entry.last_job_id, entry.last_state = rec.job_id, rec.state
        entry.profile, entry.backend, entry.overrides = rec.profile, rec.backend, dict(rec.overrides)
        entry.layer_mode = rec.layers
        entry.rtf, entry.filament_diameter_mm = rec.rtf, rec.filament_diameter_mm
        self.store.put(entry)
        return entry

    def job_changed(self, rec: s.JobRecord) -> None:
        """The job ``rec`` changed: when it is an entry's last job, the entry shows its state and plan."""
        entry = self.store.by_job(rec.job_id)
        if entry is None:
            return
        plan = rec.plan
        # a plan that cannot be timed (unreachable targets) says -1: the entry keeps 0, "no estimate"
        figures = (plan.layers, plan.extruded_mm3, max(plan.estimate_s, 0.0)) if plan is not None else \
            (entry.layers, entry.extruded_mm3, entry.estimate_s)
        if entry.last_state == rec.state and (entry.layers, entry.extruded_mm3, entry.estimate_s) == figures:
            return
        entry.last_state = rec.state
        entry.layers, entry.extruded_mm3, entry.estimate_s = figures
        self.store.put(entry)

    def page(self, query: s.FilesQuery) -> s.FileList:
        files, total = self.store.page(query.offset, query.limit, query.name_contains)
        return s.FileList(files=files, total=total, offset=query.offset)

    def remove(self, file_id: str) -> s.LibraryFile:
        """Forget the entry; its bytes stay only while a job or another entry still needs them."""
        entry = self.store.get(file_id)
        self.store.remove(entry.file_id)
        self.artifacts.unpin(_pin_owner(entry.file_id))
        return entry
