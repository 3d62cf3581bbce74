"""TLS for the servers we start (the labelling page, the Foxglove server): where they may listen.

On loopback a server is reached from this machine only. Beyond it (`host:=0.0.0.0` or an address
of the network) each person's access token travels in every request, so the server speaks TLS
(HTTPS / WSS) with a certificate and its key, or does not start unless told that the network is
trusted (Jupyter's rule, `--certfile` / `--keyfile`). `self_signed` makes a pair for a lab
(`nmrm tls cert --host NAME`); people's browsers then ask once whether to trust it.
"""

from __future__ import annotations

import ipaddress
import os
import ssl
from datetime import datetime, timedelta, timezone
from pathlib import Path

LOOPBACK = ("127.0.0.1", "localhost", "::1")


class TLSError(ValueError):
    """A certificate or key that cannot be served, or a server exposed without TLS (one line)."""


def is_loopback(host: str) -> bool:
    """True for an address only this machine can reach (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def server_context(certfile: str, keyfile: str) -> ssl.SSLContext | None:
    """The TLS context of a server (TLS 1.2 or later) from a PEM certificate (chain) and its PEM
    private key; None when neither is given. TLSError names the file and what is wrong with it."""
    certfile, keyfile = str(certfile or ""), str(keyfile or "")
    if not certfile and not keyfile:
        return None
    if not (certfile and keyfile):
        raise TLSError("certfile and keyfile go together: give both (a PEM certificate and its key) or neither")
    for what, path in (("certfile", certfile), ("keyfile", keyfile)):
        p = Path(path)
        if not p.is_file():
            raise TLSError(f"{what} {path}: no such file")
        if not os.access(p, os.R_OK):
            raise TLSError(f"{what} {path}: not readable by this user")
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        context.load_cert_chain(certfile, keyfile, password=lambda: b"")  # an encrypted key fails, never prompts
    except ssl.SSLError as exc:
        why = "the key is not the certificate's" if "KEY_VALUES_MISMATCH" in str(exc) else \
            "not a PEM certificate and its unencrypted PEM private key"
        raise TLSError(f"certfile {certfile} / keyfile {keyfile}: {why} ({exc.reason or exc})") from None
    except OSError as exc:
        raise TLSError(f"certfile {certfile} / keyfile {keyfile}: {exc.strerror or exc}") from None
    return context


def exposure_error(host: str, tls: bool, trusted_network: bool) -> str | None:
    """Why a server on `host` must not start (None: it may): beyond loopback without TLS, every
    request carries a person's token in clear text, unless the network is trusted explicitly."""
    if tls or trusted_network or is_loopback(host):
        return None
    return (f"host {host} is reachable from the network and there is no TLS: every request would carry "
            f"the access token in clear text; give certfile and keyfile (`nmrm tls cert` makes a pair), "
            f"or trusted_network:=true if this network is yours alone")


def self_signed(out_dir: str | Path, hosts: list, days: int = 365) -> tuple:
    """Write a self-signed certificate for `hosts` (DNS names and IP addresses; the first is its
    common name) and its private key (EC P-256, readable by you only) to out_dir/cert.pem and
    out_dir/key.pem; (cert path, key path). Existing files are not replaced (TLSError)."""
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
    except ImportError:
        raise TLSError("needs the Python package cryptography (pip install cryptography), or make the pair "
                       "with openssl req -x509") from None

    hosts = [str(h).strip() for h in hosts if str(h).strip()]
    if not hosts:
        raise TLSError("give at least one host name or address the certificate is for (--host)")
    if not 1 <= int(days) <= 3650:
        raise TLSError(f"days must be 1-3650, got {days}")
    names = []
    for h in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            if any(c in h for c in " /:@") or len(h) > 253:
                raise TLSError(f"{h!r} is neither a host name nor an IP address") from None
            names.append(x509.DNSName(h))
    out = Path(out_dir)
    cert_path, key_path = out / "cert.pem", out / "key.pem"
    for p in (cert_path, key_path):
        if p.exists():
            raise TLSError(f"{p} exists: not replaced (remove it, or choose another --out)")
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, hosts[0][:64]),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "nmrm_ros (self-signed)")])
    now = datetime.now(timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - timedelta(minutes=5)).not_valid_after(now + timedelta(days=int(days)))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(key, hashes.SHA256()))
    written = []
    try:
        out.mkdir(parents=True, exist_ok=True)
        for path, data, mode in ((key_path, key.private_bytes(serialization.Encoding.PEM,
                                                              serialization.PrivateFormat.PKCS8,
                                                              serialization.NoEncryption()), 0o600),
                                 (cert_path, cert.public_bytes(serialization.Encoding.PEM), 0o644)):
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
            written.append(path)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
    except OSError as exc:
        for path in written:  # nothing half-written
            path.unlink(missing_ok=True)
        raise TLSError(f"cannot write to {out}: {exc.strerror or exc}") from None
    return cert_path, key_path


def fingerprint(cert_path: str | Path) -> str:
    """The certificate's SHA-256 fingerprint, as browsers show it (AB:CD:...): what a person
    compares before trusting a self-signed certificate."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes

    cert = x509.load_pem_x509_certificate(Path(cert_path).read_bytes())
    return ":".join(f"{b:02X}" for b in cert.fingerprint(hashes.SHA256()))
