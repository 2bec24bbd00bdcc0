"""The hostile-file corpus (``benchmarks/hostile_corpus.py``) through the CLI: every case is one line
and exit code 2, never a traceback, a hang or a silent acceptance; plus the faults (a full disk) and
network peers that accept a connection and never answer."""

from __future__ import annotations

import importlib.util
import json
import os
import resource
import signal
import time
from pathlib import Path

import pytest
import cli_zygote

from conftest import run_cli

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "src" / "binpick" / "samples" / "bin_frame"


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
    ran = cli_zygote.run([*[a.format(tmp=tmp_path) for a in args]], capture_output=True, text=True, timeout=100,
                         preexec_fn=_full_disk, cwd=tmp_path)
    lines = [line for line in ran.stderr.splitlines() if line.startswith("error:")]
    assert ran.returncode == 2 and "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr[-800:]
    assert "File too large" in lines[0] or "No space" in lines[0], lines[0]
    for path in (p for p in tmp_path.rglob("*") if p.is_file()):  # atomic writes: no half file, no temporary left behind
        assert path.suffix == ".json" and json.loads(path.read_text()) is not None, path


PEER_LIMIT_S = {"silent": 60, "garbage": 60, "stalling_master": 30}  # --timeout 3 against a stalling master


@pytest.mark.timeout(120)
@pytest.mark.parametrize("kind, args, fragments", CORPUS.PEER_CASES,
                         ids=[f"{kind}-{' '.join(args[:2])}" for kind, args, _ in CORPUS.PEER_CASES])
def test_a_peer_that_never_answers_answers_garbage_or_stalls_ends_in_one_line_within_the_timeout(kind, args, fragments, tmp_path):
    config = tmp_path / "rl.yaml"
    config.write_text(CORPUS.TINY_RL_YAML)
    with CORPUS.peer(kind) as port:
        started = time.monotonic()
        ran = cli_zygote.run([*[a.format(port=port, tmp=tmp_path, config=config) for a in args]], capture_output=True,
                             text=True, timeout=100, cwd=tmp_path,
                             env=os.environ | {"ROS_HOME": str(tmp_path), "ROS_LOG_DIR": str(tmp_path / "log")})
        took = time.monotonic() - started
    lines = [line for line in ran.stderr.splitlines() if line.strip() and not line.startswith("[")]  # "[": rospy's own log
    assert ran.returncode == 2 and "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr[-800:]
    assert all(fragment in lines[0] for fragment in fragments) and took < PEER_LIMIT_S[kind], (lines[0], took)
