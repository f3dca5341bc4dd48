"""Run one service as a process: open the session, start the service, stop cleanly on SIGTERM/SIGINT."""
from __future__ import annotations

import argparse
import importlib
import logging
import signal
import threading

import zenoh

from fabric.wire.config import SessionSettings, zenoh_config
from fabric.wire.errors import FabricError
from fabric.services import SERVICE_MODULES

__all__ = ["serve", "setup_logging"]


def setup_logging(name: str, level: str = "INFO") -> None:
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO),
                        format=f"%(asctime)s {name} %(levelname)s %(message)s", datefmt="%H:%M:%S")


def serve(name: str, settings: SessionSettings, options: argparse.Namespace,
          ready: threading.Event | None = None, stop: threading.Event | None = None) -> int:
    """Run service ``name`` until ``stop`` is set or a termination signal arrives."""
    module = importlib.import_module(SERVICE_MODULES[name])
    stop = stop or threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: stop.set())
    log = logging.getLogger(f"fabric.{name}")
    try:
        session = zenoh.open(zenoh_config(settings))
    except zenoh.ZError as exc:
        from fabric.security.diagnose import explain_refusal
        why = explain_refusal(settings.config_file, settings.connect) if settings.config_file else None
        log.error("%s cannot join the fabric at %s: %s", name, ", ".join(settings.connect), why or exc)
        return 2
    with session:
        try:
            svc = module.build(session, settings.cell, options)
        except FabricError as err:
            log.error("%s cannot start: %s", name, err.message)
            return 2
        try:
            svc.start()
            if ready is not None:
                ready.set()
            stop.wait()
        except FabricError as err:
            log.error("%s cannot start: %s", name, err.message)
            return 2
        finally:
            svc.close()
    log.info("%s stopped", name)
    return 0
