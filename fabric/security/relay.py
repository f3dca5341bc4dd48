"""A relay of a secured fabric: a router for dashboards, joined to the hub with the monitor's credentials.

It listens like the hub (TLS, mutual TLS, user/password) and enforces
:func:`~fabric.security.roles.relay_access_control`: whoever connects to it has a monitor's rights. It
joins the hub as ``monitor``, so the hub, which holds the access control of the fabric, forwards nothing
from it that a monitor may not send.

A relay runs from one of two folders:

- **its own** (``fabric-cli auth export DIR relay --host HOST -o OUT``, made on the machine that holds
  ``DIR``; copy ``OUT`` to the relay's host): the CA certificate, the relay's own certificate for ``HOST``
  (common name ``relay``), a password dictionary with the monitor's password only, ``relay.json5`` (where
  it listens, the hub it links to, the monitor's certificate and password it joins with) and
  ``monitor.json5``, a dashboard's config that connects to this relay. No operator's or service's password
  or key is in it: a session with the operator's config is refused at the relay (it cannot check that
  password), in one line that says where commands go.
- **the whole credentials folder** ``DIR`` (on the hub's host): it presents the hub's certificate and
  knows every role's password, so an operator's config joins it too, with a monitor's rights.

Either way it answers ``am/@relay/<its zenoh id>`` (:data:`INFO_PREFIX`): a client connected to it learns
there that it is on a relay, which one, where the hub is and what rights it gets (``fabric.client`` asks
when a command finds no one, to say ``forbidden`` and name the relay instead of "no service").
"""
from __future__ import annotations

import base64
import binascii
import json
import os
import shutil
import ssl
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from fabric.security import pki
from fabric.security.credentials import Credentials, tls_endpoint
from fabric.security.hub import hub_zenoh_config
from fabric.security.roles import relay_access_control
from fabric.security.zconfigs import client_config, hub_config, read_json5, write_json5
from fabric.wire.config import SessionSettings
from fabric.wire.errors import ConfigError

__all__ = ["RELAY_ROLE", "RELAY_PORT", "INFO_PREFIX", "RelayFolder", "relay_zenoh_config", "relay_setup",
           "info_key", "serve_info"]

RELAY_ROLE = "monitor"            # the identity a relay joins the hub with
RELAY_PORT = 7448
INFO_PREFIX = "am/@relay"         # a verbatim chunk: no wildcard subscription of am/** matches it


def info_key(zid: str) -> str:
    """Where the relay with Zenoh id ``zid`` says what it is."""
    return f"{INFO_PREFIX}/{zid}"


def serve_info(session: zenoh.Session, info: dict[str, Any]) -> zenoh.Queryable:
    """Answer ``am/@relay/<this session's id>`` with ``info`` (msgpack): listen, hub, rights, secured."""
    import msgpack
    payload = msgpack.packb(info)
    return session.declare_queryable(info_key(str(session.info.zid())),
                                     lambda query: query.reply(query.key_expr, payload))


# --- the relay of a whole credentials folder -------------------------------------------------------------

def _field(conf: Any, path: Path, *names: str) -> Any:
    """``conf[names[0]][names[1]]...``, or a ConfigError naming the file and the missing field."""
    value = conf
    for i, name in enumerate(names):
        if not isinstance(value, dict) or name not in value:
            raise ConfigError(f"{path}: no {'/'.join(names[:i + 1])} (damaged, or not made by 'fabric-cli auth'; "
                              f"make it again)", field=str(path), missing="/".join(names[:i + 1]))
        value = value[name]
    return value


def _string(conf: Any, path: Path, *names: str) -> str:
    value = _field(conf, path, *names)
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{path}: {'/'.join(names)} is not a non-empty string (damaged? make it again)",
                          field=str(path))
    return value


def _endpoints(conf: Any, path: Path, section: str) -> list[str]:
    eps = _field(conf, path, section, "endpoints")
    if not isinstance(eps, list) or not eps or not all(isinstance(e, str) and e for e in eps):
        raise ConfigError(f"{path}: {section}/endpoints is not a list of endpoints (damaged? make it again)",
                          field=str(path))
    return list(eps)


def _joining(conf: Any, path: Path) -> dict[str, str]:
    """The credentials a relay joins the hub with, from a client config (``monitor.json5``) or ``relay.json5``."""
    out = {f"auth/usrpwd/{n}": _string(conf, path, "transport", "auth", "usrpwd", n) for n in ("user", "password")}
    for name in ("connect_private_key_base64", "connect_certificate_base64"):
        value = _string(conf, path, "transport", "link", "tls", name)
        try:
            base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError):
            raise ConfigError(f"{path}: transport/link/tls/{name} is not base64 (damaged? make it again)",
                              field=str(path)) from None
        out[f"link/tls/{name}"] = value
    return out


def relay_zenoh_config(creds: Credentials, listen: list[str], hub: list[str]) -> zenoh.Config:
    """The relay's router config from the whole credentials folder: listening on ``listen`` for dashboards
    (with the hub's certificate and dictionary), linked to the hub at ``hub`` as the monitor."""
    conf = hub_zenoh_config(creds, SessionSettings(), listen)
    conf.insert_json5("connect/endpoints", json.dumps(hub))
    conf.insert_json5("access_control", json.dumps(relay_access_control()))
    path = creds.config(RELAY_ROLE)
    for field, value in _joining(read_json5(path), path).items():         # user, password, certificate, key
        conf.insert_json5(f"transport/{field}", json.dumps(value))
    conf.insert_json5("transport/link/tls/verify_name_on_connect", "true")
    return conf


# --- a relay's own folder ----------------------------------------------------------------------------------

def check_pem(path: Path, what: str, key: Path | None = None) -> None:
    """A certificate (with its key, when given) that TLS can load; else a ConfigError naming the file."""
    for p in (path, key):
        if p is not None and not p.is_file():
            raise ConfigError(f"{p} is missing ({what}): export the folder again", field=str(p))
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    try:
        if key is None:
            ctx.load_verify_locations(cafile=str(path))
        else:
            ctx.load_cert_chain(str(path), str(key))
    except (ssl.SSLError, ValueError, OSError) as exc:
        named = f"{path}" if key is None else f"{path} / {key.name}"
        raise ConfigError(f"{named}: not a usable {what} ({getattr(exc, 'reason', None) or exc}): export the "
                          f"folder again", field=str(path)) from None


def read_dictionary(path: Path) -> dict[str, str]:
    """A ``user:password`` dictionary; a ConfigError naming the file when it is missing or malformed."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read it ({exc.strerror})", field=str(path)) from None
    out: dict[str, str] = {}
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise ConfigError(f"{path}: line {n} is not user:password (damaged? export the folder again)",
                              field=str(path), line=n)
        out[user] = password
    if not out:
        raise ConfigError(f"{path}: no user:password line (damaged? export the folder again)", field=str(path))
    return out


@dataclass(frozen=True)
class RelayFolder:
    """What one relay host holds (``fabric-cli auth export DIR relay --host HOST -o OUT``)."""

    root: Path

    @property
    def ca_cert(self) -> Path: return self.root / "ca.pem"
    @property
    def cert(self) -> Path: return self.root / "relay-cert.pem"
    @property
    def key(self) -> Path: return self.root / "relay-key.pem"
    @property
    def passwords(self) -> Path: return self.root / "passwords.txt"
    @property
    def config(self) -> Path: return self.root / "relay.json5"
    @property
    def dashboard(self) -> Path: return self.root / f"{RELAY_ROLE}.json5"

    FILES = ("ca.pem", "relay-cert.pem", "relay-key.pem", "passwords.txt", "relay.json5", "monitor.json5")

    @staticmethod
    def holds_one(root: Path) -> bool:
        """Whether ``root`` is a relay's folder (not a whole credentials folder)."""
        return (root / "relay.json5").exists() and not (root / "hub.json5").exists()

    @classmethod
    def export(cls, creds: Credentials, out: str | Path, host: str, hosts: list[str] | None = None,
               listen: str | None = None, force: bool = False) -> RelayFolder:
        """Write the folder of a relay on ``host`` (its name or address, as dashboards reach it) from the whole
        credentials folder ``creds`` (its CA key signs the relay's certificate)."""
        creds.check()
        if not creds.ca_key.is_file():
            raise ConfigError(f"{creds.ca_key} is missing: exporting a relay signs its certificate with the CA's "
                              f"key; run it where the key is kept", field=str(creds.ca_key))
        listen = listen or f"tls/0.0.0.0:{RELAY_PORT}"
        _, port = tls_endpoint(listen, "--listen")
        name = host.strip("[]")
        if not name or "/" in name or " " in name:
            raise ConfigError(f"--host {host!r}: give the relay host's name or address", field="--host", value=host)
        hub = creds.hub_endpoints()
        if any(tls_endpoint(ep, "hub")[0] == name and tls_endpoint(ep, "hub")[1] == port for ep in hub):
            raise ConfigError(f"the relay would listen where the hub is ({', '.join(hub)}): give it another port "
                              f"(--listen tls/0.0.0.0:PORT)", field="--listen", value=listen)
        password = creds.read_passwords().get(RELAY_ROLE)
        if not password:
            raise ConfigError(f"{creds.passwords}: no {RELAY_ROLE} password (damaged? 'fabric-cli auth passwd "
                              f"{creds.root} {RELAY_ROLE}' sets one)", field=str(creds.passwords))
        folder = cls(Path(out).resolve())
        if folder.root == creds.root:
            raise ConfigError("export the relay's folder elsewhere than the credentials folder", field="-o")
        if folder.root.exists() and any(folder.root.iterdir()):
            if not force:
                raise ConfigError(f"{folder.root} is not empty (--force replaces what a relay's folder holds)",
                                  field="-o", value=str(folder.root))
            if (folder.root / "hub.json5").exists():
                raise ConfigError(f"{folder.root} holds a whole credentials folder: export elsewhere", field="-o")
        folder.root.mkdir(parents=True, exist_ok=True)
        folder.root.chmod(0o700)
        for stale in cls.FILES:
            (folder.root / stale).unlink(missing_ok=True)
        shutil.copyfile(creds.ca_cert, folder.ca_cert)
        pki.issue(folder.cert, folder.key, "relay", [name, *(hosts or []), "localhost", "127.0.0.1", "::1"],
                  creds.ca_cert, creds.ca_key)
        fd = os.open(folder.passwords, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{RELAY_ROLE}:{password}\n")
        monitor = read_json5(creds.config(RELAY_ROLE))
        joining = _joining(monitor, creds.config(RELAY_ROLE))
        conf = hub_config([listen], folder.passwords, folder.ca_cert, folder.cert, folder.key, relay_access_control())
        conf["connect"] = {"endpoints": hub}
        for field, value in joining.items():
            outer, inner, item = field.split("/")
            conf["transport"][outer][inner][item] = value
        conf["transport"]["link"]["tls"]["verify_name_on_connect"] = True
        write_json5(folder.config, conf,
                    f"am-fabric relay on {name}: fabric-cli relay --secure {folder.root.name}\n"
                    f"listens on {listen} for dashboards; links to the hub at {', '.join(hub)} as {RELAY_ROLE}\n"
                    "holds the monitor's password and key: keep it readable by the relay's user only")
        dash = f"tls/{'[' + name + ']' if ':' in name else name}:{port}"
        write_json5(folder.dashboard,
                    client_config(RELAY_ROLE, [dash], RELAY_ROLE, password, creds.ca_cert, creds.cert(RELAY_ROLE),
                                  creds.key(RELAY_ROLE)),
                    f"am-fabric dashboard through the relay at {dash}: fabric-cli --config {folder.dashboard.name}, "
                    f"fabric-tui --config, or zenoh.Config.from_file\n"
                    "holds the monitor's password and key: keep it readable by its user only")
        return folder

    # --- reading ---------------------------------------------------------------------------------------

    def _conf(self) -> dict[str, Any]:
        if not self.config.is_file():
            raise ConfigError(f"{self.config} is missing: make the folder with 'fabric-cli auth export DIR relay "
                              f"--host HOST -o {self.root}'", field=str(self.config))
        conf = read_json5(self.config)
        if not isinstance(conf, dict):
            raise ConfigError(f"{self.config}: not a relay's config (export the folder again)", field=str(self.config))
        return conf

    def hub_endpoints(self) -> list[str]:
        return _endpoints(self._conf(), self.config, "connect")

    def listen_endpoints(self) -> list[str]:
        return _endpoints(self._conf(), self.config, "listen")

    def zenoh_config(self, listen: list[str] | None = None, hub: list[str] | None = None) -> zenoh.Config:
        """The relay's router config, every file checked first (each problem one ConfigError naming its file);
        the files are taken from where the folder is now (it was written elsewhere, then copied)."""
        conf = self._conf()
        listen = list(listen or _endpoints(conf, self.config, "listen"))
        hub = list(hub or _endpoints(conf, self.config, "connect"))
        _joining(conf, self.config)
        _field(conf, self.config, "access_control")
        if _field(conf, self.config, "mode") != "router":
            raise ConfigError(f"{self.config}: mode is not router (not a relay's config: export the folder again)",
                              field=str(self.config))
        check_pem(self.ca_cert, "CA certificate")
        check_pem(self.cert, "certificate and key of the relay", self.key)
        read_dictionary(self.passwords)
        conf["listen"] = {"endpoints": listen}
        conf["connect"] = {"endpoints": hub}
        conf["transport"]["auth"]["usrpwd"]["dictionary_file"] = str(self.passwords)
        tls = _field(conf, self.config, "transport", "link", "tls")
        tls.update(root_ca_certificate=str(self.ca_cert), listen_certificate=str(self.cert),
                   listen_private_key=str(self.key))
        try:
            return zenoh.Config.from_json5(json.dumps(conf))
        except zenoh.ZError as exc:
            raise ConfigError(f"{self.config}: Zenoh refuses it ({str(exc).split(' at /')[0]})",
                              field=str(self.config)) from None


def relay_setup(folder: Path, listen: list[str] | None, connect: list[str] | None
                ) -> tuple[zenoh.Config, list[str], list[str]]:
    """The router config of a secured relay from ``folder`` (a relay's own, or the whole credentials folder),
    where it listens and the hub it links to (``listen``/``connect`` override the folder's)."""
    root = folder.resolve()
    if RelayFolder.holds_one(root):
        relay = RelayFolder(root)
        conf = relay.zenoh_config(listen, connect)
        return conf, list(listen or relay.listen_endpoints()), list(connect or relay.hub_endpoints())
    if not (root / "hub.json5").exists() and not (root / "relay.json5").exists():
        raise ConfigError(f"{root} holds neither a relay's folder (relay.json5: 'fabric-cli auth export DIR relay "
                          f"--host HOST -o {root}') nor a credentials folder (hub.json5: make the folder with "
                          f"'fabric-cli auth init {root}')", field="--secure", value=str(root))
    creds = Credentials(root).check()
    if not listen:
        raise ConfigError("a relay needs --listen ENDPOINT: where dashboards connect to it", field="--listen")
    hub = list(connect or creds.hub_endpoints())
    return relay_zenoh_config(creds, list(listen), hub), list(listen), hub
