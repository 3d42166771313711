"""Application instance certificates for OPC UA: a key pair and a self-signed certificate.

An OPC UA application's X.509 certificate holds its application URI (``URI:urn:...``)
and host (``DNS:`` or ``IP:``) as subject alternative names (IEC 62541-6, 6.2.2), key
usage for signing and key encipherment, and the role as extended key usage (client
authentication for ``czmpc run``, server for a served plant).

`create_application_certificate` writes::

    DIR/own/<name>.der    the certificate (DER, what OPC UA stacks exchange)
    DIR/own/<name>.pem    the RSA private key (PEM, unencrypted, mode 0600)

The certificate is self-signed: it is copied into the other side's trusted store (a
server's ``pki/trusted/certs``), and the server's is pinned in the run config
(``server_certificate``).
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from czmpc.errors import CzmpcError, SettingsError

#: RSA key length [bit]: Basic256Sha256 asks for 2048 to 4096.
KEY_BITS = 2048
#: Validity of a new certificate [days] (plant IT usually rotates yearly or longer).
VALIDITY_DAYS = 825

Role = Literal["client", "server", "both"]


@dataclass(frozen=True, kw_only=True)
class CertificateFiles:
    """Where `create_application_certificate` wrote the certificate and its key.

    Parameters
    ----------
    certificate :
        The DER certificate.
    private_key :
        The PEM private key (mode 0600).
    sha1_thumbprint :
        SHA-1 thumbprint of the certificate, hex (what OPC UA tools show).
    """

    certificate: Path
    private_key: Path
    sha1_thumbprint: str


def _crypto() -> Any:
    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import rsa
        from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID
    except ImportError as exc:  # pragma: no cover - installed with the opcua extra
        raise CzmpcError("certificates need the 'cryptography' package: pip install 'czmpc[opcua]'") from exc
    return x509, hashes, serialization, rsa, ExtendedKeyUsageOID, NameOID


def create_application_certificate(
    out_dir: str | os.PathLike[str], *, app_uri: str, host: str, name: str = "czmpc",
    role: Role = "client", force: bool = False, now: dt.datetime | None = None,
) -> CertificateFiles:
    """Make an RSA key pair and a self-signed OPC UA application instance certificate.

    Parameters
    ----------
    out_dir :
        PKI directory; files go to ``out_dir/own/``.
    app_uri :
        Application URI, e.g. ``urn:plant-a:czmpc`` (the application's configured one).
    host :
        Host name or IP address the application runs on (subject alternative name).
    name :
        File stem and common name.
    role :
        Extended key usage: ``client``, ``server`` or ``both``.
    force :
        Replace existing files (otherwise refused).
    now :
        Start of validity (default: the current UTC time); for reproducible tests.

    Returns
    -------
    CertificateFiles

    Raises
    ------
    SettingsError
        An empty URI or host, or files that exist without ``force``.
    """
    if not app_uri or ":" not in app_uri:
        raise SettingsError(f"pki: --app-uri must be a URI such as 'urn:plant:czmpc'; got {app_uri!r}")
    if not host:
        raise SettingsError("pki: --host must name the machine (host name or IP address)")
    x509, hashes, serialization, rsa, eku, name_oid = _crypto()
    own = Path(out_dir) / "own"
    cert_path, key_path = own / f"{name}.der", own / f"{name}.pem"
    existing = [p for p in (cert_path, key_path) if p.exists()]
    if existing and not force:
        raise SettingsError(f"pki: {', '.join(map(str, existing))} exist; pass --force to replace them")
    own.mkdir(parents=True, exist_ok=True)
    key = rsa.generate_private_key(public_exponent=65537, key_size=KEY_BITS)
    subject = x509.Name([x509.NameAttribute(name_oid.COMMON_NAME, name),
                         x509.NameAttribute(name_oid.ORGANIZATION_NAME, "czmpc")])
    try:
        host_name = x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        host_name = x509.DNSName(host)
    usages = {"client": [eku.CLIENT_AUTH], "server": [eku.SERVER_AUTH],
              "both": [eku.CLIENT_AUTH, eku.SERVER_AUTH]}[role]
    start = now if now is not None else dt.datetime.now(dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject).issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(start - dt.timedelta(minutes=5))
        .not_valid_after(start + dt.timedelta(days=VALIDITY_DAYS))
        .add_extension(x509.SubjectAlternativeName([x509.UniformResourceIdentifier(app_uri), host_name]),
                       critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True,
                                     key_encipherment=True, data_encipherment=True,
                                     key_agreement=False, key_cert_sign=False, crl_sign=False,
                                     encipher_only=False, decipher_only=False), critical=True)
        .add_extension(x509.ExtendedKeyUsage(usages), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.TraditionalOpenSSL,
                            serialization.NoEncryption())
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(pem)
    os.chmod(key_path, 0o600)   # also when the file existed with a wider mode
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    return CertificateFiles(certificate=cert_path, private_key=key_path,
                            sha1_thumbprint=cert.fingerprint(hashes.SHA1()).hex())


def application_uri(certificate_der: bytes) -> str | None:
    """The application URI in a DER certificate's subject alternative names, or None."""
    x509 = _crypto()[0]
    cert = x509.load_der_x509_certificate(certificate_der)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return str(uris[0]) if uris else None


__all__ = ["KEY_BITS", "VALIDITY_DAYS", "CertificateFiles", "application_uri",
           "create_application_certificate"]
