"""The five services, one module each: ``fabric.services.<name>`` for each name of ``fabric.wire.keys.SERVICES``."""
from fabric.wire.keys import SERVICES

SERVICE_MODULES = {name: f"fabric.services.{name}" for name in SERVICES}
