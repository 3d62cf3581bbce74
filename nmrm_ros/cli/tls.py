"""`nmrm tls cert`: a self-signed certificate for serving the labelling page or Foxglove on a network."""

from __future__ import annotations

from pathlib import Path

import typer

from .app import app
from .common import writable_dir

tls_app = typer.Typer(help="TLS for the servers we start (labeller_web, foxglove_server) beyond loopback.",
                      no_args_is_help=True)
app.add_typer(tls_app, name="tls")


@tls_app.command("cert")
def cert(
    host: list[str] = typer.Option(..., "--host", help="a name or address people will type to reach this "
                                                       "machine (repeat for each: --host lab-pc --host 192.168.1.20)"),
    out: Path = typer.Option(Path("tls"), callback=writable_dir,
                             help="directory for cert.pem and key.pem (not replaced if there)"),
    days: int = typer.Option(365, min=1, max=3650, help="days the certificate is valid"),
) -> None:
    """Make a self-signed certificate and key for a lab network; serve with
    certfile:=OUT/cert.pem keyfile:=OUT/key.pem (docs/guide/labelling.md, "On a network")."""
    from ..tls import fingerprint, self_signed

    cert_path, key_path = self_signed(out, host, days)
    typer.echo(f"wrote {cert_path} and {key_path} (readable by you only), for {', '.join(host)}, valid {days} days")
    typer.echo(f"SHA-256 fingerprint (people compare it with what their browser shows): {fingerprint(cert_path)}")
    typer.echo(f"serve with: certfile:={cert_path} keyfile:={key_path}")
