"""The hostile-file corpus (``benchmarks/hostile_corpus.py``) through the CLI: every case is one line
and exit code 2, never a traceback, a hang or a silent acceptance; plus the faults (a full disk) and
network peers that accept a connection and never answer."""

from __future__ import annotations

import importlib.util
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from conftest import run_cli

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "src" / "binpick" / "samples" / "bin_frame"
CLI = [sys.executable, "-c", "from binpick.cli import main; main()"]


def corpus_module():
    spec = importlib.util.spec_from_file_location("hostile_corpus", ROOT / "benchmarks" / "hostile_corpus.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


CORPUS = corpus_module()


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> dict[str, str]:
    return CORPUS.make_corpus(tmp_path_factory.mktemp("hostile"))


def _ids() -> list[str]:
    return [f"{i:02d}-{klass}-" + "-".join(a.strip("{}").replace("/", "_")[:16] for a in args[1:4]) for i, (klass, args, _)
            in enumerate(CORPUS.CASES)]


@pytest.mark.timeout(60)  # a case that hangs fails here instead of blocking the suite
@pytest.mark.parametrize("klass,args,fragments", CORPUS.CASES, ids=_ids())
def test_every_hostile_file_is_one_line(klass, args, fragments, corpus, capsys, monkeypatch):
    code, err = run_cli([a.format(**corpus) for a in args], capsys, monkeypatch, corpus["root"])
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, (code, err[-600:])  # refused: never accepted
    assert lines[0].startswith("error: ")
    for fragment in fragments:
        assert fragment.format(**corpus) in lines[0], lines[0]


def test_the_corpus_covers_every_class():
    classes = {klass for klass, _, _ in CORPUS.CASES}
    assert classes == {"files", "frames", "configs", "data"} and len(CORPUS.CASES) >= 85


def test_nothing_escaped_the_runs_folder():
    assert not Path("/tmp/binpick-escaped-run").exists()


def _full_disk() -> None:
    """In the child: files may grow to 200 bytes (writing more fails as on a full disk)."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (200, 200))


@pytest.mark.timeout(120)
@pytest.mark.parametrize("args", [
    ["plan", "--sample", "--out", "{tmp}/plan"],
    ["detect", "predict", str(SAMPLE / "rgb.png"), "--weights", str(ROOT / "src" / "binpick" / "detection" / "weights" / "rod_tiny_320.safetensors"), "--query-box", "393,279,93,59", "--out", "{tmp}/p"],
], ids=["plan", "predict"])
def test_a_full_disk_is_one_line_and_leaves_no_half_file(args, tmp_path):
    ran = subprocess.run([*CLI, *[a.format(tmp=tmp_path) for a in args]], capture_output=True, text=True, timeout=100,
                         preexec_fn=_full_disk, cwd=tmp_path)
    lines = [line for line in ran.stderr.splitlines() if line.startswith("error:")]
    assert ran.returncode == 2 and "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr[-800:]
    assert "File too large" in lines[0] or "No space" in lines[0], lines[0]
    for path in (p for p in tmp_path.rglob("*") if p.is_file()):  # atomic writes: no half file, no temporary left behind
        assert path.suffix == ".json" and json.loads(path.read_text()) is not None, path


def _peer(on_connection):
    """A listener on 127.0.0.1 whose every accepted connection goes to ``on_connection(connection,
    held)`` on a thread of its own; yields the port, then closes the listener and what ``held`` keeps."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(16)
    held: list[socket.socket] = []

    def accept() -> None:
        while True:
            try:
                connection = server.accept()[0]
            except OSError:
                return
            threading.Thread(target=on_connection, args=(connection, held), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    yield server.getsockname()[1]
    server.close()
    for connection in held:
        connection.close()


@pytest.fixture
def silent_peer():
    """A listener on 127.0.0.1 that accepts every connection and never sends a byte."""
    yield from _peer(lambda connection, held: held.append(connection))


@pytest.fixture
def garbage_peer():
    """A listener on 127.0.0.1 that answers every connection with bytes of no protocol, then holds it open."""
    def answer(connection: socket.socket, held: list) -> None:
        try:
            connection.sendall(b"\x00\xffgarbage, not a protocol\r\n" * 8)
        except OSError:
            return
        held.append(connection)

    yield from _peer(answer)


@pytest.fixture
def stalling_master():
    """An XML-RPC peer on 127.0.0.1 that answers getPid as a ROS master does and then never answers again."""
    answer = (b"HTTP/1.0 200 OK\r\nContent-Type: text/xml\r\n\r\n<?xml version='1.0'?><methodResponse><params><param><value>"
              b"<array><data><value><int>1</int></value><value><string>ok</string></value><value><int>42</int></value>"
              b"</data></array></value></param></params></methodResponse>")

    def handle(connection: socket.socket, held: list) -> None:
        request = b""
        connection.settimeout(10)
        try:
            while b"</methodCall>" not in request:
                chunk = connection.recv(4096)
                if not chunk:
                    return
                request += chunk
        except OSError:
            return
        if b"getPid" in request:
            connection.sendall(answer)
            connection.close()
        else:
            held.append(connection)  # a stall: the request is read and never answered

    yield from _peer(handle)


@pytest.mark.timeout(120)
@pytest.mark.parametrize("args", [
    ["ros", "pick-node", "--master", "http://127.0.0.1:{port}/", "--timeout", "3", "--camera", str(SAMPLE / "camera.yaml")],
    ["ros", "serve", "FetchReach", "--master", "http://127.0.0.1:{port}/", "--timeout", "3"],
    ["ros", "bench", "--master", "http://127.0.0.1:{port}/", "--timeout", "3"],
], ids=["pick-node", "serve", "bench"])
def test_a_ros_master_that_answers_then_stalls_ends_in_one_line_within_the_timeout(args, stalling_master, tmp_path):
    started = time.monotonic()
    ran = subprocess.run([*CLI, *[a.format(port=stalling_master) for a in args]], capture_output=True, text=True, timeout=100,
                         cwd=tmp_path, env=os.environ | {"ROS_HOME": str(tmp_path), "ROS_LOG_DIR": str(tmp_path / "log")})
    lines = [line for line in ran.stderr.splitlines() if line.strip() and not line.startswith("[")]
    assert ran.returncode == 2 and "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr[-800:]
    assert "stopped answering" in lines[0] and time.monotonic() - started < 30


@pytest.mark.timeout(120)
@pytest.mark.parametrize("args,fragment", [
    (["train", "{config}", "--runs", "{tmp}/runs", "--address", "127.0.0.1:{port}"], "not as a Ray cluster does"),
    (["ros", "pick-node", "--master", "http://127.0.0.1:{port}/", "--camera", str(SAMPLE / "camera.yaml")], "ROS master"),
], ids=["ray", "ros-master"])
def test_a_peer_that_answers_garbage_ends_in_one_line_within_the_timeout(args, fragment, garbage_peer, tmp_path):
    config = tmp_path / "rl.yaml"
    config.write_text("task: rl\nname: tiny\nenv: FetchReach\nalgorithm: sac\ntotal_timesteps: 200\n")
    started = time.monotonic()
    ran = subprocess.run([*CLI, *[a.format(port=garbage_peer, tmp=tmp_path, config=config) for a in args]], capture_output=True,
                         text=True, timeout=100, cwd=tmp_path)
    lines = [line for line in ran.stderr.splitlines() if line.strip()]
    assert ran.returncode == 2 and "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr[-800:]
    assert fragment in lines[0] and time.monotonic() - started < 60


@pytest.mark.timeout(120)
@pytest.mark.parametrize("args,fragment", [
    (["rl", "distributed", "--address", "127.0.0.1:{port}", "--steps", "1000", "--out", "{tmp}/d"], "did not answer within"),
    (["data", "generate", "--out", "{tmp}/g", "--address", "127.0.0.1:{port}", "--scenes", "1"], "did not answer within"),
    (["ros", "pick-node", "--master", "http://127.0.0.1:{port}/", "--camera", str(SAMPLE / "camera.yaml")], "no ROS master answered"),
], ids=["ray-rollouts", "ray-data", "ros-master"])
def test_a_peer_that_never_answers_ends_in_one_line_within_the_timeout(args, fragment, silent_peer, tmp_path):
    started = time.monotonic()
    ran = subprocess.run([*CLI, *[a.format(port=silent_peer, tmp=tmp_path) for a in args]], capture_output=True, text=True,
                         timeout=100, cwd=tmp_path)
    lines = [line for line in ran.stderr.splitlines() if line.strip()]
    assert ran.returncode == 2 and "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr[-800:]
    assert fragment in lines[0] and time.monotonic() - started < 60
