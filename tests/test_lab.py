"""``make lab``: JupyterLab starts in the project's environment with the notebooks, on localhost; the test starts it
with --no-browser on a free port, finds it in ``jupyter server list --json``, asks its REST API for the notebooks and
stops it (all within a bounded time)."""
from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
START_TIMEOUT_S = 180.0      # `make lab` first brings .venv up to date (nothing to do after `make test`)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def server_list(jupyter: Path, env: dict) -> list[dict]:
    out = subprocess.run([str(jupyter), "server", "list", "--json"], capture_output=True, text=True, env=env,
                         timeout=60)
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as r:
        return json.loads(r.read())


@pytest.mark.skipif(shutil.which("make") is None or not sys.platform.startswith("linux"),
                    reason="needs make (and /proc for the environment check)")
@pytest.mark.skipif(Path(sys.prefix).resolve() != (REPO / ".venv").resolve(),
                    reason="`make lab` runs in the project's .venv: run this test from it (`make test`)")
def test_make_lab_starts_jupyterlab_with_the_notebooks(tmp_path):
    jupyter = Path(sys.executable).parent / "jupyter"
    assert jupyter.exists(), "jupyterlab is not installed in the test environment (the test extra has it)"
    env = {**os.environ, "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime"),
           "JUPYTER_CONFIG_DIR": str(tmp_path / "config"), "JUPYTERLAB_WORKSPACES_DIR": str(tmp_path / "ws")}
    port, token = free_port(), secrets.token_hex(16)
    args = f"--no-browser --port={port} --ServerApp.port_retries=0 --IdentityProvider.token={token}"
    log = (tmp_path / "lab.log").open("w")
    proc = subprocess.Popen(["make", "-C", str(REPO), "lab", f"LAB_ARGS={args}"], stdout=log, stderr=subprocess.STDOUT,
                            env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        server = None
        while server is None and time.monotonic() < deadline:
            assert proc.poll() is None, f"make lab exited: {(tmp_path / 'lab.log').read_text()[-2000:]}"
            server = next((s for s in server_list(jupyter, env) if s["port"] == port), None)
            time.sleep(1.0)
        assert server is not None, f"no server on port {port}: {(tmp_path / 'lab.log').read_text()[-2000:]}"
        assert server["hostname"] == "localhost" and server["url"].startswith(f"http://localhost:{port}/")
        assert Path(server["root_dir"]) == REPO / "notebooks"
        base = f"http://localhost:{port}/api"
        assert "started" in get(f"{base}/status?token={token}")
        listed = {c["name"] for c in get(f"{base}/contents?token={token}")["content"]}
        assert {p.name for p in (REPO / "notebooks").glob("*.ipynb")} <= listed
        assert get(f"{base}/kernelspecs?token={token}")["default"] == "python3"
        cmdline = Path(f"/proc/{server['pid']}/cmdline").read_bytes().split(b"\0")
        assert Path(cmdline[0].decode()).parent == Path(sys.executable).parent, cmdline   # the project's venv
        stop = subprocess.run([str(jupyter), "server", "stop", str(port)], capture_output=True, text=True, env=env,
                              timeout=60)
        assert stop.returncode == 0, stop.stderr
        assert proc.wait(timeout=60) == 0
        assert not [s for s in server_list(jupyter, env) if s["port"] == port]
    finally:
        if proc.poll() is None:                                    # only the process group this test started
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
        log.close()
