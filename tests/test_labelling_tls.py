"""The labelling page (and the Foxglove server) for people on a network: TLS, the refusal to serve
beyond loopback in clear text, and a page that says what to judge. Real processes, a real
certificate made by `nmrm tls cert`, requests over real TLS, the page in the real browser."""

from __future__ import annotations

import base64
import hashlib
import http.client
import json
import re
import signal
import socket
import ssl
import subprocess
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from nmrm_ros.testing.graph import Capture, executable, finish, start

from test_labeller_web import ARTEFACTS, CHROMIUM, WebNode, play_episodes


def _network_address() -> str | None:
    """An address of this machine other than loopback (None where it has none)."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))  # no packet is sent: the route says which address is ours
            address = s.getsockname()[0]
    except OSError:
        return None
    return None if address.startswith("127.") else address


@pytest.fixture(scope="module")
def certificate(tmp_path_factory):
    """cert.pem and key.pem for 127.0.0.1, localhost, this machine's name and network address,
    made by the documented command."""
    out = tmp_path_factory.mktemp("tls")
    hosts = ["127.0.0.1", "localhost", socket.gethostname()] + ([_network_address()] if _network_address() else [])
    run = subprocess.run([executable("nmrm"), "tls", "cert", "--out", str(out),
                          *[a for h in hosts for a in ("--host", h)]], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert "SHA-256 fingerprint" in run.stdout and (out / "key.pem").stat().st_mode & 0o077 == 0
    again = subprocess.run([executable("nmrm"), "tls", "cert", "--out", str(out), "--host", "x"],
                           capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and "exists: not replaced" in again.stderr and len(again.stderr.splitlines()) == 1
    return out / "cert.pem", out / "key.pem"


def _client_context(cert: Path) -> ssl.SSLContext:
    return ssl.create_default_context(cafile=str(cert))


def _spki_hash(cert: Path) -> str:
    """base64 SHA-256 of the certificate's public key: what Chromium's
    --ignore-certificate-errors-spki-list trusts (this certificate only)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    key = x509.load_pem_x509_certificate(cert.read_bytes()).public_key()
    der = key.public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)
    return base64.b64encode(hashlib.sha256(der).digest()).decode()


def _request(url: str, context: ssl.SSLContext, token: str, body: dict | None = None,
             headers: dict | None = None) -> tuple:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method="POST" if data is not None else "GET")
    req.add_header("X-Token", token)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    for k, v in (headers or {}).items():
        req.add_header(k, v)
    try:
        with urllib.request.urlopen(req, timeout=10, context=context) as r:
            text = r.read()
            is_json = r.headers.get("Content-Type", "").startswith("application/json")
            return r.status, json.loads(text) if is_json else text.decode(), r.headers
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read()), exc.headers


def test_beyond_loopback_without_tls_the_servers_do_not_start(ros_domain, tmp_path, certificate):
    """host:=0.0.0.0 without a certificate: labeller_web and foxglove_server exit 2 with one line
    saying why (and what to give); with trusted_network:=true they start. A missing certificate,
    a file that is not one, a key that is not the certificate's, an instruction file that is not
    UTF-8 text: one line each, no labels dir left."""
    cert, key = certificate
    other_key = tmp_path / "other"
    subprocess.run([executable("nmrm"), "tls", "cert", "--out", str(other_key), "--host", "x"], check=True,
                   capture_output=True, timeout=60)
    not_pem = tmp_path / "not.pem"
    not_pem.write_text("hello\n")
    from cryptography.hazmat.primitives import serialization

    locked = tmp_path / "locked.pem"  # the same key, encrypted: refused, never a passphrase prompt
    locked.write_bytes(serialization.load_pem_private_key(key.read_bytes(), None).private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
        serialization.BestAvailableEncryption(b"secret")))
    cases = [({"host": "0.0.0.0"}, "clear text"),
             ({"certfile": str(tmp_path / "none.pem"), "keyfile": str(key)}, "no such file"),
             ({"certfile": str(not_pem), "keyfile": str(key)}, "not a PEM certificate"),
             ({"certfile": str(cert), "keyfile": str(other_key / "key.pem")}, "the key is not the certificate's"),
             ({"certfile": str(cert), "keyfile": str(locked)}, "unencrypted PEM private key"),
             ({"certfile": str(cert)}, "go together")]
    for node in ("labeller_web", "foxglove_server"):
        for params, why in cases:
            labels = tmp_path / f"labels_{node}"
            extra = {"labels_dir": str(labels)} if node == "labeller_web" else {}
            code, out = finish(start(node, port=0, **params, **extra), 60)
            errors = [line for line in out.splitlines() if "ERROR" in line or "error" in line]
            assert code == 2 and why in out and len(errors) == 1, (node, params, out)
            assert "Traceback" not in out and not labels.exists(), (node, params, out)
        if node == "labeller_web":  # the instruction file: missing, a directory, not text, empty
            binary, empty = tmp_path / "binary.txt", tmp_path / "empty.txt"
            binary.write_bytes(b"\xff\xfe\x00bad")
            empty.write_text("  \n")
            for path, why in ((tmp_path / "none.txt", "No such file"), (tmp_path, "a directory"),
                              (binary, "not UTF-8"), (empty, "0 characters")):
                code, out = finish(start(node, port=0, instruction=str(path), **extra), 60)
                assert code == 2 and why in out and "Traceback" not in out, (path, out)
        proc = start(node, port=0, host="0.0.0.0", trusted_network=True, **extra)
        try:
            line = ""
            for line in proc.stdout:
                if "labelling page: " in line or "Foxglove: " in line:
                    break
            assert f"://{socket.gethostname()}:" in line, line
        finally:
            proc.terminate()
            finish(proc, 30)


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (scripts/test.sh installs it with "
                                             "apt when run as root)")
def test_a_person_labels_over_https_and_sees_what_to_judge(ros_domain, tmp_path, certificate):
    """labeller_web with a certificate, on every address, for a team of two: each URL printed is
    https:// (a token appears there only: not on /rosout, which the network can read); a plain-HTTP request to the port gets
    no answer; another origin's POST is refused; the cookie is Secure. In Chromium (trusting
    this certificate only) through this machine's network address, alice's page shows the Key
    task's instruction, a legend of the zones, start, path and step, the keys and her counts,
    and her label reaches the node. Screenshot: build/test_artefacts/labelling_page_tls.png."""
    from playwright.sync_api import expect, sync_playwright

    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    cert, key = certificate
    address = _network_address() or "127.0.0.1"
    capture = Capture()  # reads /rosout: what anyone on the DDS network can read
    rosout: list = []
    capture.node.create_subscription(Log, "/rosout", lambda m: rosout.append(m.msg), QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node = WebNode(tmp_path / "labels", certfile=str(cert), keyfile=str(key), host="0.0.0.0",
                   people="[alice, bob]")
    try:
        url = node.url
        assert url.startswith(f"https://{socket.gethostname()}:"), node.lines
        port, token = int(url.split(":")[2].split("/")[0]), url.split("token=")[1]
        base = f"https://{address}:{port}"
        context = _client_context(cert)
        play_episodes(2)
        status, queue, _ = _request(base + "/api/queue", context, token)
        assert status == 200
        # plain HTTP to the TLS port: no answer, and nothing labelled
        conn = http.client.HTTPConnection(address, port, timeout=10)
        with pytest.raises((ConnectionError, http.client.HTTPException, OSError)):
            conn.request("GET", f"/api/queue?token={token}")
            conn.getresponse()
        conn.close()
        status, answer, _ = _request(base + "/api/label", context, token, {"episode": 0, "return": 1.0},
                                     headers={"Origin": f"https://evil.example:{port}"})
        assert status == 403 and "cross-origin" in answer["error"], answer
        status, _, headers = _request(base + f"/?token={token}", context, "")
        assert status == 200 and "Secure" in headers["Set-Cookie"] and "HttpOnly" in headers["Set-Cookie"]

        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=[
                "--no-sandbox", f"--ignore-certificate-errors-spki-list={_spki_hash(cert)}"])
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            errors: list = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"{base}/?token={token}")
            page.wait_for_selector("#queue li")
            assert "only once the agent has been in the blue key zone" in page.text_content("#instruction")
            legend = page.text_content("#legend")
            for words in ("key: visit it first", "treasure: +1 a step once the key is collected",
                          "where the episode starts", "the path so far", "where it is at the step shown"):
                assert words in legend, legend
            assert page.locator("#legend .zone-swatch.zone-key").count() == 1
            assert "Enter: give the return typed" in page.text_content("#shortcuts")
            page.wait_for_selector("#arena circle.start")
            expect(page.locator("#counts")).to_have_text(re.compile(r"^0 return\(s\) given, [12] episode\(s\) wait$"))
            ARTEFACTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(ARTEFACTS / "labelling_page_tls.png"), full_page=True)
            page.fill("#return", "3.5")
            page.click("#submit")
            page.wait_for_selector("#history tr")
            expect(page.locator("#counts")).to_have_text(re.compile(r"^1 return\(s\) given, [01] episode\(s\) wait$"))
            assert errors == []
            browser.close()
        assert capture.spin_until(lambda: any("labelled episode" in m for m in rosout), 20), rosout
        assert not any(token in m for m in rosout), rosout
    finally:
        out = node.stop()
        capture.close()
    assert "labelled episode" in out, out
    assert sum(token in line for line in out.splitlines()) == 1, out  # her URL's line only
    assert all(line.split("labelling page: ")[1].startswith("https://") for line in out.splitlines()
               if "labelling page: " in line), out


def test_the_foxglove_server_speaks_wss_only_with_a_certificate(ros_domain, certificate):
    """foxglove_server with a certificate: its URL is wss://; a WebSocket client that trusts the
    certificate gets the server's info over TLS; a plain ws:// handshake to the port gets nothing."""
    import asyncio

    import aiohttp

    cert, key = certificate
    proc = start("foxglove_server", port=0, certfile=str(cert), keyfile=str(key), token="test-token-123")
    try:
        line = ""
        for line in proc.stdout:
            if "Foxglove: " in line:
                break
        url = line.split("Foxglove: ")[1].split()[0]
        assert url.startswith("wss://127.0.0.1:") and "app.foxglove.dev" in line, line
        port = int(url.split(":")[2].split("/")[0])

        async def connect(scheme: str, context):
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(f"{scheme}://127.0.0.1:{port}/?token=test-token-123",
                                              ssl=context if context is not None else True,
                                              protocols=("foxglove.websocket.v1",),
                                              timeout=aiohttp.ClientWSTimeout(ws_close=10)) as ws:
                    return json.loads((await ws.receive(timeout=10)).data)

        info = asyncio.run(connect("wss", _client_context(cert)))
        assert info["op"] == "serverInfo", info
        with pytest.raises((aiohttp.ClientError, asyncio.TimeoutError, ConnectionError)):
            asyncio.run(asyncio.wait_for(connect("ws", None), 20))
    finally:
        proc.send_signal(2)
        finish(proc, 30)


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (scripts/test.sh installs it with "
                                             "apt when run as root)")
def test_two_people_on_another_machine_label_a_label_launch_session_over_https(ros_domain, tmp_path, certificate):
    """The docs' commands on two "machines" (network namespaces joined by a veth link; root only):
    the lab machine runs `nmrm launch label.launch.yaml` for [alice, bob] on every address with a
    certificate made by `nmrm tls cert --host <its address>`; on the other machine Chromium
    (trusting that certificate only) opens each person's https:// URL: each sees what to judge and
    labels the episode the page gives them, and the session logs both labels.
    Screenshots: build/test_artefacts/labelling_page_tls_{alice,bob}.png."""
    import os

    from playwright.sync_api import sync_playwright

    from nmrm_ros.testing.netns import HostsUnavailable, in_host, make_hosts, remove_hosts

    try:
        hosts, namespaces = make_hosts(routed=False)
    except HostsUnavailable as exc:
        pytest.skip(str(exc))
    session = None
    try:
        lab, desk = hosts.robot, hosts.workstation
        tls = tmp_path / "tls"
        made = subprocess.run([executable("nmrm"), "tls", "cert", "--host", hosts.robot_ip, "--out", str(tls)],
                              capture_output=True, text=True, timeout=60)
        assert made.returncode == 0, made.stderr
        start_model = subprocess.run([executable("nmrm"), "train", "--task", "key", "--n", "60", "--epochs", "1",
                                      "--ensemble", "2", "--out", str(tmp_path / "start")],
                                     capture_output=True, text=True, timeout=300)
        assert start_model.returncode == 0, start_model.stderr
        launch_file = Path(__file__).resolve().parents[1] / "launch_scripts" / "label.launch.yaml"
        session = in_host(lab, os.environ.copy(), executable("nmrm"), "launch", str(launch_file),
                          f"checkpoint:={tmp_path / 'start.pt'}", "people:=[alice, bob]", "episodes:=3",
                          "host:=0.0.0.0", "port:=0", f"certfile:={tls / 'cert.pem'}", f"keyfile:={tls / 'key.pem'}",
                          f"out:={tmp_path / 'session'}")
        lines, urls = [], {}
        for line in session.stdout:
            lines.append(line)
            if "labelling page: " in line:
                person = line.split("labeller person/")[1].split(",")[0]
                urls[person] = line.split("labelling page: ")[1].split()[0]
            if len(urls) == 2:
                break
        assert set(urls) == {"alice", "bob"} and all(u.startswith("https://") for u in urls.values()), "".join(lines)
        reader = threading.Thread(target=lambda: lines.extend(session.stdout), daemon=True)
        reader.start()
        wrapper = tmp_path / "chromium_on_the_other_machine"
        wrapper.write_text(f'#!/bin/sh\nexec ip netns exec {desk} {CHROMIUM} "$@"\n')
        wrapper.chmod(0o755)
        given = {}
        ARTEFACTS.mkdir(parents=True, exist_ok=True)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=str(wrapper), args=[
                "--no-sandbox", f"--ignore-certificate-errors-spki-list={_spki_hash(tls / 'cert.pem')}"])
            for n, person in enumerate(("alice", "bob")):
                port, token = urls[person].split(":")[2].split("/")[0], urls[person].split("token=")[1]
                page = browser.new_page(viewport={"width": 1200, "height": 900})
                errors: list = []
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.goto(f"https://{hosts.robot_ip}:{port}/?token={token}", timeout=60_000)
                page.wait_for_selector("#arena polyline", timeout=60_000)
                assert page.text_content("#who").startswith(f"person/{person}")
                assert "blue key zone" in page.text_content("#instruction")
                assert "key: visit it first" in page.text_content("#legend")
                given[person] = int(page.text_content("#title").split()[1])
                page.screenshot(path=str(ARTEFACTS / f"labelling_page_tls_{person}.png"), full_page=True)
                page.fill("#return", str(10 + n))
                page.click("#submit")
                page.wait_for_selector("#history tr")
                assert errors == []
            browser.close()
        assert given["alice"] != given["bob"], given  # split: each episode to one person
        deadline = time.monotonic() + 30
        want = [f"person/{p} labelled episode {given[p]}: return {10 + n}" for n, p in enumerate(("alice", "bob"))]
        while not all(any(w in line for line in lines) for w in want) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert all(any(w in line for line in lines) for w in want), "".join(lines)
    finally:
        if session is not None and session.poll() is None:
            session.send_signal(signal.SIGINT)
            try:
                session.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(session.pid, signal.SIGKILL)
        remove_hosts(namespaces)
