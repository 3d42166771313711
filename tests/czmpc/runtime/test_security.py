"""czmpc.runtime.security and .pki: the [plant.security] table, checked before any connection."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID
from opcua_rig import PASSWORD, PASSWORD_ENV, USER, Pki

from czmpc.cli import main
from czmpc.errors import SettingsError
from czmpc.runtime.security import (
    INSECURE_LOOPBACK,
    Secret,
    is_loopback_endpoint,
    parse_security,
)

REMOTE = "opc.tcp://10.1.2.3:4840/plc/"


def _table(pki: Pki, **extra: object) -> dict[str, object]:
    table: dict[str, object] = {
        "policy": "Basic256Sha256", "mode": "SignAndEncrypt",
        "certificate": str(pki.client_cert), "private_key": str(pki.client_key),
        "server_certificate": str(pki.server_cert), "username": USER, "password_env": PASSWORD_ENV,
    }
    table.update(extra)
    return table


@pytest.mark.parametrize(("endpoint", "loopback"), [
    ("opc.tcp://127.0.0.1:4840/x/", True), ("opc.tcp://localhost:4840", True),
    ("opc.tcp://[::1]:4840/", True), ("opc.tcp://127.8.0.1:1/", True),
    (REMOTE, False), ("opc.tcp://plc.plant.local:4840/", False),
])
def test_loopback_endpoints_are_recognised(endpoint: str, loopback: bool) -> None:
    assert is_loopback_endpoint(endpoint) is loopback


def test_no_table_connects_only_to_loopback(tmp_path: Path) -> None:
    assert parse_security(None, endpoint="opc.tcp://127.0.0.1:4840/", base_dir=tmp_path) is INSECURE_LOOPBACK
    with pytest.raises(SettingsError, match=r"not a loopback address.*\[plant.security\]"):
        parse_security(None, endpoint=REMOTE, base_dir=tmp_path)
    with pytest.raises(SettingsError, match=r"policy = \"None\" is allowed only for a loopback"):
        parse_security({"policy": "None"}, endpoint=REMOTE, base_dir=tmp_path)


def test_full_table_is_parsed_and_the_password_never_shows(pki: Pki) -> None:
    settings = parse_security(_table(pki), endpoint=REMOTE, base_dir=pki.dir,
                              environ={PASSWORD_ENV: PASSWORD})
    assert settings.secure and settings.username == USER
    assert settings.password is not None and settings.password.reveal() == PASSWORD
    for text in (repr(settings), str(settings), settings.describe(), f"{settings.password}",
                 repr(settings.password)):
        assert PASSWORD not in text
    assert "Basic256Sha256 SignAndEncrypt" in settings.describe()


def test_password_in_the_file_is_refused_naming_password_env(pki: Pki) -> None:
    with pytest.raises(SettingsError, match=r"password must not be written.*password_env") as info:
        parse_security(_table(pki, password=PASSWORD), endpoint=REMOTE, base_dir=pki.dir)
    assert PASSWORD not in str(info.value)


def test_private_key_readable_by_others_is_refused(pki: Pki, tmp_path: Path) -> None:
    loose = tmp_path / "loose.pem"
    loose.write_bytes(pki.client_key.read_bytes())
    os.chmod(loose, 0o644)
    with pytest.raises(SettingsError, match=r"accessible by other users \(mode 644\).*chmod 600"):
        parse_security(_table(pki, private_key=str(loose)), endpoint=REMOTE, base_dir=pki.dir,
                       environ={PASSWORD_ENV: PASSWORD})


@pytest.mark.parametrize(("change", "match"), [
    ({"policy": "Basic128Rsa15"}, r"policy must be one of"),
    ({"mode": "None"}, r"mode must be one of"),
    ({"certificate": "missing.der"}, r"certificate: no such file"),
    ({"colour": "red"}, r"unknown key\(s\) \['colour'\]"),
    ({"password_env": "CZMPC_UNSET_FOR_TEST"}, r"CZMPC_UNSET_FOR_TEST is not set"),
])
def test_bad_tables_say_which_key(pki: Pki, change: dict[str, object], match: str) -> None:
    with pytest.raises(SettingsError, match=match):
        parse_security(_table(pki, **change), endpoint=REMOTE, base_dir=pki.dir, environ={})


def test_secret_compares_by_value_only_inside() -> None:
    assert Secret("a") == Secret("a") and Secret("a") != Secret("b") and "a" not in repr(Secret("a"))


def test_pki_create_makes_an_application_certificate_for_opc_ua(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["pki", "create", "--out", str(tmp_path), "--app-uri", "urn:plant-a:czmpc", "--host", "mpc-pc"]
    assert main(argv) == 0
    cert = x509.load_der_x509_certificate((tmp_path / "own" / "czmpc.der").read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.UniformResourceIdentifier) == ["urn:plant-a:czmpc"]
    assert san.get_values_for_type(x509.DNSName) == ["mpc-pc"]
    usage = cert.extensions.get_extension_for_class(x509.KeyUsage).value
    assert usage.digital_signature and usage.key_encipherment and usage.data_encipherment
    assert not usage.key_cert_sign
    assert list(cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value) == [
        ExtendedKeyUsageOID.CLIENT_AUTH]
    assert (tmp_path / "own" / "czmpc.pem").stat().st_mode & 0o777 == 0o600
    assert "SHA-1 thumbprint" in capsys.readouterr().out
    assert main(argv) == 2                                   # refuses to overwrite
    assert "--force" in capsys.readouterr().err
    assert main([*argv, "--force"]) == 0
