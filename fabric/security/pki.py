"""A small certificate authority made with the ``openssl`` command line: one CA, one certificate per identity.

Keys are ECDSA P-256 in PKCS#8 PEM (what rustls, under Zenoh's TLS links, reads). Every
certificate names its identity in the common name (the hub's access control matches it) and
carries the host names and addresses it may be reached at (checked by whoever connects to it).
"""
from __future__ import annotations

import ipaddress
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from fabric.wire.errors import ConfigError

__all__ = ["make_ca", "issue", "subject_alt_names"]

CA_DAYS = 3650
CERT_DAYS = 825


def _openssl(*args: str) -> None:
    exe = shutil.which("openssl")
    if exe is None:
        raise ConfigError("the 'openssl' command is needed to make certificates (apt-get install openssl)",
                          field="openssl")
    done = subprocess.run([exe, *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise ConfigError(f"openssl {args[0]} failed: {done.stderr.strip().splitlines()[-1:]}", field="openssl")


def _new_key(path: Path) -> None:
    _openssl("genpkey", "-algorithm", "EC", "-pkeyopt", "ec_paramgen_curve:P-256", "-out", str(path))
    os.chmod(path, 0o600)


def make_ca(cert: Path, key: Path, name: str = "am-fabric CA") -> None:
    """A self-signed CA certificate and its key."""
    _new_key(key)
    _openssl("req", "-x509", "-new", "-key", str(key), "-sha256", "-days", str(CA_DAYS), "-subj", f"/CN={name}",
             "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
             "-out", str(cert))


def subject_alt_names(names: list[str]) -> str:
    """``DNS:a,IP:1.2.3.4,...`` for host names and addresses (duplicates dropped, order kept)."""
    out: list[str] = []
    for name in dict.fromkeys(names):
        try:
            out.append(f"IP:{ipaddress.ip_address(name)}")
        except ValueError:
            out.append(f"DNS:{name}")
    return ",".join(out)


def issue(cert: Path, key: Path, common_name: str, hosts: list[str], ca_cert: Path, ca_key: Path) -> None:
    """A certificate for ``common_name`` signed by the CA, usable as TLS server and client."""
    _new_key(key)
    with tempfile.TemporaryDirectory(prefix="am-fabric-pki-") as tmp:
        csr, ext = Path(tmp) / "req.csr", Path(tmp) / "cert.ext"
        _openssl("req", "-new", "-key", str(key), "-subj", f"/CN={common_name}", "-out", str(csr))
        ext.write_text("basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\n"
                       "extendedKeyUsage=serverAuth,clientAuth\n"
                       f"subjectAltName={subject_alt_names([common_name, *hosts])}\n")
        _openssl("x509", "-req", "-in", str(csr), "-CA", str(ca_cert), "-CAkey", str(ca_key), "-CAcreateserial",
                 "-CAserial", str(Path(tmp) / "ca.srl"), "-days", str(CERT_DAYS), "-sha256", "-extfile", str(ext),
                 "-out", str(cert))
