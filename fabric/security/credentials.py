"""A credentials folder: what ``fabric-cli auth init DIR`` writes and ``fabric-cli up --secure DIR`` reads.

Layout of ``DIR``::

    ca.pem ca-key.pem                  the fabric's certificate authority (keep ca-key.pem offline)
    hub-cert.pem hub-key.pem           the hub's TLS certificate (its host names and addresses)
    <role>-cert.pem <role>-key.pem     one certificate per role (common name = role)
    passwords.txt                      the hub's user/password dictionary (``user:password`` lines)
    hub.json5                          the hub's Zenoh config: TLS only, mTLS, passwords, access control
    operator.json5 monitor.json5 service.json5     one self-contained client config per role

A relay's host gets a folder of its own instead (``fabric-cli auth export DIR relay``:
:class:`fabric.security.relay.RelayFolder`). Every file is read into a typed ``ConfigError`` naming it when it
is missing or damaged, never a KeyError.
"""
from __future__ import annotations

import re
import secrets
from dataclasses import dataclass
from pathlib import Path

from fabric.security import pki
from fabric.security.roles import ROLES, access_control
from fabric.security.zconfigs import client_config, hub_config, read_json5, write_json5
from fabric.wire.errors import ConfigError

__all__ = ["Credentials", "DEFAULT_SECURE_HUB", "tls_endpoint"]

DEFAULT_SECURE_HUB = "tls/127.0.0.1:7447"
_ENDPOINT_RE = re.compile(r"^tls/(\[[0-9a-fA-F:]+\]|[^:/\[\]]+):(\d+)$")
_LOOPBACK = ("localhost", "127.0.0.1", "::1")


def tls_endpoint(endpoint: str, what: str = "hub") -> tuple[str, str]:
    """(host, port) of ``tls/<host>:<port>``; a ConfigError for anything else (a secured fabric speaks TLS only)."""
    m = _ENDPOINT_RE.match(endpoint)
    if not m:
        raise ConfigError(f"{what} endpoint {endpoint!r} must be tls/<host>:<port> (a secured fabric speaks TLS "
                          f"only)", field=what, value=endpoint)
    return m.group(1).strip("[]"), m.group(2)


def _endpoints(path: Path, section: str) -> list[str]:
    """The ``<section>/endpoints`` of a config written by ``auth init``; a ConfigError naming the file when it
    is damaged (never a KeyError)."""
    conf = read_json5(path)
    eps = conf.get(section) if isinstance(conf, dict) else None
    eps = eps.get("endpoints") if isinstance(eps, dict) else None
    if not isinstance(eps, list) or not eps or not all(isinstance(e, str) and e for e in eps):
        raise ConfigError(f"{path}: no {section}/endpoints (damaged? 'fabric-cli auth init {path.parent} --force' "
                          f"makes the folder again)", field=str(path), missing=f"{section}/endpoints")
    return list(eps)


@dataclass(frozen=True)
class Credentials:
    """The files of one credentials folder (nothing is read until asked)."""

    root: Path

    @property
    def ca_cert(self) -> Path: return self.root / "ca.pem"
    @property
    def ca_key(self) -> Path: return self.root / "ca-key.pem"
    @property
    def passwords(self) -> Path: return self.root / "passwords.txt"
    @property
    def hub_config(self) -> Path: return self.root / "hub.json5"

    def cert(self, name: str) -> Path:
        return self.root / f"{name}-cert.pem"

    def key(self, name: str) -> Path:
        return self.root / f"{name}-key.pem"

    def config(self, role: str) -> Path:
        """The client config of ``role`` (``--config`` of fabric-cli, fabric-tui, or plain zenoh)."""
        if role not in ROLES:
            raise ConfigError(f"no role {role!r} (roles: {', '.join(ROLES)})", field="role", value=role)
        return self.root / f"{role}.json5"

    # --- reading --------------------------------------------------------------

    def check(self) -> Credentials:
        """Raise ConfigError naming the first missing file (a folder not made by ``auth init``)."""
        for path in (self.ca_cert, self.passwords, self.hub_config, self.cert("hub"), self.key("hub"),
                     *(self.config(r) for r in ROLES)):
            if not path.is_file():
                raise ConfigError(f"{path} is missing: make the folder with 'fabric-cli auth init {self.root}'",
                                  field=str(path))
        return self

    def hub_endpoints(self) -> list[str]:
        """Where clients connect (the ``connect`` endpoints of the operator's config)."""
        return _endpoints(self.config("operator"), "connect")

    def listen_endpoints(self) -> list[str]:
        """Where the hub listens."""
        return _endpoints(self.hub_config, "listen")

    # --- making -----------------------------------------------------------------

    @classmethod
    def init(cls, root: str | Path, hub: str = DEFAULT_SECURE_HUB, listen: str | None = None,
             hosts: list[str] | None = None, force: bool = False) -> Credentials:
        """Make a CA, certificates, passwords and every config in ``root`` (refuses to overwrite unless ``force``).

        ``hub``: where clients connect (``tls/<host>:<port>``); ``listen``: where the hub listens (default:
        ``hub`` on loopback, else every address on its port); ``hosts``: more names or addresses of the hub.
        """
        creds = cls(Path(root).resolve())
        host, port = tls_endpoint(hub, "hub")
        listen = listen or (hub if host in _LOOPBACK else f"tls/0.0.0.0:{port}")
        tls_endpoint(listen, "hub listen")
        creds.root.mkdir(parents=True, exist_ok=True)
        creds.root.chmod(0o700)
        if creds.hub_config.exists() and not force:
            raise ConfigError(f"{creds.root} already holds credentials (--force makes new ones: every client "
                              f"then needs its new config)", field="dir", value=str(creds.root))
        pki.make_ca(creds.ca_cert, creds.ca_key)
        pki.issue(creds.cert("hub"), creds.key("hub"), "hub", [host, *(hosts or []), *_LOOPBACK],
                  creds.ca_cert, creds.ca_key)
        passwords = {role: secrets.token_urlsafe(18) for role in ROLES}
        for role in ROLES:
            pki.issue(creds.cert(role), creds.key(role), role, [], creds.ca_cert, creds.ca_key)
            creds._write_client(role, [hub], passwords[role])
        creds._write_passwords(passwords)
        write_json5(creds.hub_config, hub_config([listen], creds.passwords, creds.ca_cert, creds.cert("hub"),
                                                 creds.key("hub"), access_control()),
                    "am-fabric hub (fabric-cli up --secure DIR, or fabric-cli router --secure DIR)")
        return creds

    def rotate(self, role: str, password: str | None = None) -> str:
        """Give ``role`` a new password (in the dictionary and its config); returns it. The hub reads the
        dictionary when it starts: restart it, then hand out the new config."""
        self.check()
        password = password or secrets.token_urlsafe(18)
        if ":" in password or "\n" in password or not password:
            raise ConfigError("a password may not be empty nor hold ':' or a line break", field="password")
        passwords = self.read_passwords()
        passwords[role] = password
        self._write_client(role, self.hub_endpoints(), password)
        self._write_passwords(passwords)
        return password

    def _write_client(self, role: str, connect: list[str], password: str) -> None:
        conf = client_config(role, connect, role, password, self.ca_cert, self.cert(role), self.key(role))
        write_json5(self.config(role), conf,
                    f"am-fabric {role}: fabric-cli --config {self.config(role).name}, or zenoh.Config.from_file\n"
                    "holds a password and a private key: keep it readable by its user only")

    def read_passwords(self) -> dict[str, str]:
        """The hub's dictionary: user -> password (a ConfigError naming the file when it cannot be read)."""
        try:
            text = self.passwords.read_text()
        except OSError as exc:
            raise ConfigError(f"{self.passwords}: cannot read it ({exc.strerror})", field=str(self.passwords)) from None
        out = {}
        for line in text.splitlines():
            user, sep, password = line.partition(":")
            if sep:
                out[user] = password
        return out

    def _write_passwords(self, passwords: dict[str, str]) -> None:
        tmp = self.passwords.with_suffix(".tmp")
        tmp.write_text("".join(f"{user}:{pw}\n" for user, pw in passwords.items()))
        tmp.chmod(0o600)
        tmp.replace(self.passwords)
