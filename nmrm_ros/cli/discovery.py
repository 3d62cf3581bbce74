"""`nmrm discovery-server`: a Fast DDS discovery server for graphs across hosts."""

from __future__ import annotations

import typer

from .app import app


@app.command("discovery-server")
def discovery_server(
    server_id: int = typer.Option(0, "--id", min=0, max=255, help="server id (its position in ROS_DISCOVERY_SERVER)"),
    address: str = typer.Option("0.0.0.0", help="address to listen on"),
    port: int = typer.Option(11811, min=1025, max=65535, help="UDP port (Fast DDS: 1025-65535)"),
) -> None:
    """Run a Fast DDS Discovery Server (for networks without multicast); nodes then need
    ROS_DISCOVERY_SERVER=ADDRESS:PORT (docs/guide/several-machines.md). Ctrl-C stops it."""
    import os

    from ..ros.discovery_server import server_command

    try:
        argv, env = server_command(server_id, address, port)
    except FileNotFoundError as exc:
        raise typer.BadParameter(str(exc)) from None
    os.execve(argv[0], argv, env)


