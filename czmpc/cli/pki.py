"""Make czmpc's OPC UA application instance certificate and private key.

    czmpc pki create --out pki --app-uri urn:plant-a:czmpc --host mpc-pc.plant-a.local

writes pki/own/czmpc.der (self-signed certificate, DER) and pki/own/czmpc.pem (RSA 2048
private key, mode 0600) and says what to do next; --role server makes a served plant's.
Guide: docs/guides/plant_link.rst, "Secure the link to a real plant".
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "pki"
HELP = "make an OPC UA application certificate and key for a secure plant link"


def register(parser: argparse.ArgumentParser) -> None:
    """Add this command's options."""
    sub = parser.add_subparsers(dest="pki_action", metavar="ACTION", required=True)
    create = sub.add_parser("create", help="key pair and self-signed application certificate",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    create.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="PKI directory; files go to DIR/own/")
    create.add_argument("--app-uri", metavar="URI", required=True,
                        help="application URI, e.g. urn:plant-a:czmpc (subject alternative name)")
    create.add_argument("--host", metavar="HOST", required=True,
                        help="host name or IP address this application runs on")
    create.add_argument("--name", default="czmpc", help="file stem and common name (default: czmpc)")
    create.add_argument("--role", choices=("client", "server", "both"), default="client",
                        help="extended key usage: client for 'czmpc run', server for 'czmpc plant "
                             "serve' (default: client)")
    create.add_argument("--force", action="store_true", help="replace existing files")


def run(args: argparse.Namespace) -> int:
    """Write the certificate and key, print where they are and the thumbprint."""
    from czmpc.runtime.pki import create_application_certificate

    files = create_application_certificate(args.out, app_uri=args.app_uri, host=args.host,
                                           name=args.name, role=args.role, force=args.force)
    print(f"certificate: {files.certificate}\nprivate key: {files.private_key} (mode 600)\n"
          f"SHA-1 thumbprint: {files.sha1_thumbprint}\n"
          f"next: have {files.certificate.name} trusted by the plant's OPC UA server, and pin the "
          f"server's certificate as [plant.security] server_certificate in the run config")
    return 0
