"""Hostile and broken input, counted: every case of the hostile-file corpus through the CLI, a full
disk, network peers that never answer, answer garbage or (a ROS master) stall after one answer,
``--address auto`` with no cluster, and the hostile ROS messages sent to both
running nodes; plus the peak memory of planning on a 4000x3000 frame and of refusing a 30000x30000
image header.

    python benchmarks/hostile.py [--skip-ros]

Each case ends one of four ways: one error line and exit code 2 (refused, as it should be; warnings about
the input before it allowed), a traceback,
a hang (past its timeout) or a silent acceptance (exit code 0, or any other code without one clean
line). Writes results/hostile.json (cases_by_class, totals, ros, peak_rss_mib) and the hostile-input
section of docs/RESULTS.md. Targets: 0 tracebacks, 0 hangs, 0 silent acceptances.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

ROOT = _common.ROOT
SAMPLE = ROOT / "src" / "binpick" / "samples" / "bin_frame"
CLI = [sys.executable, "-c", "from binpick.cli import main; main()"]
TIMEOUT = 60


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def outcome(code, err: str, fragments: list[str]) -> str:
    """How a refused case ended: one ``error:`` line and exit code 2 is a clean refusal (``warning:`` lines
    before it, about the input as read, and rospy's own ``[...]`` log lines are allowed); anything else
    with a traceback is one; the rest silent."""
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith(("warning: ", "["))]  # "[": rospy's log
    if "Traceback" in err:
        return "traceback"
    if code == 2 and len(lines) == 1 and lines[0].startswith("error: "):
        return "one_line" if all(f in lines[0] for f in fragments) else "one_line_other_reason"
    return "silent_acceptance"


def run_in_process(args: list[str], fragments: list[str]) -> str:
    from binpick.cli import main

    def alarm(*_):
        raise TimeoutError("hang")

    own, sys.argv = sys.argv, ["binpick", *args]
    out, err = io.StringIO(), io.StringIO()
    signal.signal(signal.SIGALRM, alarm)
    signal.alarm(TIMEOUT)
    code = None
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main()
                code = 0
            except SystemExit as exit_:
                code = exit_.code
    except TimeoutError:
        return "hang"
    except BaseException:  # noqa: BLE001 - an exception main() let through is a traceback to the user
        return "traceback"
    finally:
        signal.alarm(0)
        sys.argv = own
    return outcome(code, err.getvalue(), fragments)


def run_child(args: list[str], fragments: list[str], cwd: Path, preexec=None) -> str:
    try:
        ran = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=TIMEOUT + 30, cwd=cwd, preexec_fn=preexec)
    except subprocess.TimeoutExpired:
        return "hang"
    return outcome(ran.returncode, ran.stderr, fragments)


def full_disk() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (200, 200))


def peak_rss_mib(args: list[str], cwd: Path) -> tuple[float, int, str]:
    """Peak resident memory (MiB) of one CLI run (the child's own, from wait4), its exit code and last line."""
    with tempfile.TemporaryFile("w+") as err:
        child = subprocess.Popen([*CLI, *args], stdout=subprocess.DEVNULL, stderr=err, cwd=cwd)
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        lines = err.read().strip().splitlines()
    return round(usage.ru_maxrss / 1024, 1), child.returncode, (lines[-1] if lines else "")[:160]


def big_frame(folder: Path) -> list[str]:
    """The sample frame at 4000x3000 (colour and depth, a camera scaled to match)."""
    import numpy as np
    import yaml
    from PIL import Image

    Image.open(SAMPLE / "rgb.png").convert("RGB").resize((4000, 3000), Image.BILINEAR).save(folder / "rgb.png")
    depth = np.array(Image.open(SAMPLE / "depth.png"))
    Image.fromarray(np.kron(depth, np.ones((12, 12), depth.dtype)).astype(np.uint16)[:3000, :4000]).save(folder / "depth.png")
    camera = yaml.safe_load((SAMPLE / "camera.yaml").read_text())
    scale = 4000 / camera["image_width"]
    k = camera["camera_matrix"]["data"]
    camera["camera_matrix"]["data"] = [k[0] * scale, 0.0, (k[2] + 0.5) * scale - 0.5, 0.0, k[4] * scale, (k[5] + 0.5) * scale - 0.5, 0, 0, 1]
    camera["projection_matrix"]["data"] = [*camera["camera_matrix"]["data"][:3], 0.0, *camera["camera_matrix"]["data"][3:6], 0.0, 0, 0, 1, 0]
    camera["image_width"], camera["image_height"] = 4000, 3000
    (folder / "camera.yaml").write_text(yaml.safe_dump(camera))
    return ["plan", "--rgb", str(folder / "rgb.png"), "--depth", str(folder / "depth.png"), "--camera", str(folder / "camera.yaml"),
            "--query-box", ",".join(str(v * 6.25) for v in (393, 279, 93, 59)), "--out", str(folder / "plan")]


def ros_hostile(version: int) -> dict:
    loop = str(ROOT / "benchmarks" / "ros_loop.py")
    common = ["--orders", "1", "--goal", "id", "--hostile", "--timeout", "120", "--products", "robosuite/can"]
    if version == 1:
        command = [sys.executable, loop, "--ros", "1", *common]
    else:
        python = ROOT / ".venv-ros2" / "bin" / "python"
        command = ["unshare", "-n", "sh", "-c", f"ip link set lo up && exec {python} {loop} --ros 2 {' '.join(common)}"]
    ran = subprocess.run(command, capture_output=True, text=True, timeout=600)
    if ran.returncode != 0:
        return {"error": ran.stderr.strip().splitlines()[-1:] if ran.stderr.strip() else ran.returncode}
    summary = json.loads(ran.stdout.strip().splitlines()[-1])
    hostile = summary["hostile"]
    return {"camera_messages": hostile["camera_messages"], "goals": hostile["goals"],
            "goals_answered_with_reason": hostile["answered_with_reason"],
            "good_goal_after": "placed" if summary["placed"] == summary["orders"] else "not placed",
            "node_alive": hostile["node_alive_at_end"], "tracebacks_in_node_log": hostile["tracebacks_in_node_log"],
            "camera_warnings_in_node_log": hostile["camera_warnings_in_node_log"],
            "camera_messages_dropped": hostile["camera_messages_dropped"], "camera_internal_errors": hostile.get("camera_internal_errors", 0), "interfaces": summary["interfaces"],
            "node_log_tail": ran.stderr.strip().splitlines()[-3:]}


def section(result: dict) -> str:
    """The hostile-input section of docs/RESULTS.md, from results/hostile.json."""
    totals, peak = result["totals"], result["peak_rss_mib"]
    rows = [f"| {klass} | {t['cases']} | {t['one_line']} | {t['one_line_other_reason']} | {t['tracebacks']} | {t['hangs']} | "
            f"{t['silent_acceptances']} |" for klass, t in result["cases_by_class"].items()]
    lines = ["## Hostile and broken input", "",
             f"`benchmarks/hostile.py`: the hostile-file corpus (`benchmarks/hostile_corpus.py`) through the CLI, a full disk, "
             f"network peers that never answer, answer garbage or stall after one answer (a ROS master), `--address auto` "
             f"without a cluster, and hostile ROS messages to both running nodes ({result['ros_messages_sent']} in all: "
             "bad goals answered with their reason, bad camera messages dropped, then a good goal placed; ROS 2 inside a "
             "loopback-only network namespace). 'One line': refused with one line naming the problem (for a goal: an "
             "aborted result). Target: 0 tracebacks, 0 hangs, 0 silent acceptances.", "",
             "| class | cases | one line | one line, other reason | tracebacks | hangs | silent acceptances |",
             "|---|---|---|---|---|---|---|", *rows,
             f"| **all** | {totals['cases']} | {totals['one_line']} | {totals['one_line_other_reason']} | {totals['tracebacks']} | "
             f"{totals['hangs']} | {totals['silent_acceptances']} |", "",
             f"Peak memory: `binpick plan` on a 4000x3000 frame {peak['plan_4000x3000']} MiB (exit {peak['plan_4000x3000_exit_code']}); "
             f"`detect predict` on a 30000x30000 PNG header {peak['detect_predict_30000x30000_header']} MiB (refused before decoding, "
             f"exit {peak['detect_predict_30000x30000_exit_code']})."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-ros", action="store_true")
    args = parser.parse_args()
    corpus = load("hostile_corpus")
    work = Path(tempfile.mkdtemp(prefix="binpick-hostile-"))
    paths = corpus.make_corpus(work / "corpus")
    os.chdir(work / "corpus")
    counts: dict[str, dict[str, int]] = {}
    failures = []

    def count(klass: str, result: str, case: str) -> None:
        tally = counts.setdefault(klass, {"cases": 0, "one_line": 0, "one_line_other_reason": 0, "tracebacks": 0, "hangs": 0,
                                          "silent_acceptances": 0})
        tally["cases"] += 1
        tally[{"traceback": "tracebacks", "hang": "hangs", "silent_acceptance": "silent_acceptances"}.get(result, result)] += 1
        if result not in ("one_line",):
            failures.append({"class": klass, "case": case, "result": result})

    started = time.time()
    for klass, argv, fragments in corpus.CASES:
        args_ = [a.format(**paths) for a in argv]
        count(klass, run_in_process(args_, [f.format(**paths) for f in fragments]), " ".join(argv)[:120])
    print(f"corpus: {len(corpus.CASES)} cases in {time.time() - started:.0f} s", flush=True)
    for argv in (["plan", "--sample", "--out", "plan"],
                 ["detect", "predict", str(SAMPLE / "rgb.png"), "--weights",
                  str(ROOT / "src/binpick/detection/weights/rod_tiny_320.safetensors"), "--query-box", "393,279,93,59", "--out", "predict"]):
        folder = Path(tempfile.mkdtemp(dir=work))
        count("faults", run_child(argv, ["File too large"], folder, full_disk), "full disk: " + " ".join(argv[:3]))
    config = work / "rl.yaml"
    config.write_text(corpus.TINY_RL_YAML)
    for kind, argv, fragments in corpus.PEER_CASES:  # peers that never answer, answer garbage, or stall after one answer
        with corpus.peer(kind) as port:
            folder = Path(tempfile.mkdtemp(dir=work))
            tick = time.monotonic()
            result = run_child([a.format(port=port, tmp=folder, config=config) for a in argv], fragments, folder)
        count("network", result if time.monotonic() - tick < TIMEOUT else "hang", f"{kind} peer: " + " ".join(argv[:2]))
    tick = time.monotonic()  # no cluster to join
    result = run_child(["train", str(config), "--runs", str(work / "auto"), "--address", "auto"], ["no Ray cluster"], work)
    count("network", result if time.monotonic() - tick < TIMEOUT else "hang", "--address auto without a cluster")
    ros = {} if args.skip_ros else {"ros1": ros_hostile(1), "ros2": ros_hostile(2)}
    for name, tally in ros.items():  # every hostile message is a case: a bad goal must be answered with its reason; a
        # bad camera message dropped (the node counts what it drops and prints it when it stops; no traceback, the node
        # alive and the good goal after them placed)
        healthy = (tally.get("node_alive") and tally.get("good_goal_after") == "placed" and tally.get("tracebacks_in_node_log") == 0
                   and tally.get("camera_internal_errors", 0) == 0)  # an internal error is a failure, never a refusal
        answered = tally.get("goals_answered_with_reason", 0) if healthy else 0
        for index in range(tally.get("goals", 0)):
            count("ros_messages", "one_line" if index < answered else "silent_acceptance", f"{name} goal {index}")
        dropped = tally.get("camera_messages_dropped", 0) if healthy else 0  # counted by the node, printed when it stops
        internal = tally.get("camera_internal_errors", 0)  # the node's own code failed on them: tracebacks, not silence
        for index in range(tally.get("camera_messages", 0)):
            outcome = "one_line" if index < dropped else "traceback" if index < dropped + internal else "silent_acceptance"
            count("ros_messages", outcome, f"{name} camera message {index}")
    big = work / "big"
    big.mkdir()
    plan_rss, plan_code, plan_line = peak_rss_mib(big_frame(big), big)
    header_rss, header_code, header_line = peak_rss_mib(["detect", "predict", paths["bomb_png"], "--weights", paths["weights"],
                                                         "--query-box", "1,1,5,5"], work)
    totals = {key: sum(t[key] for t in counts.values()) for key in ("cases", "one_line", "one_line_other_reason", "tracebacks",
                                                                     "hangs", "silent_acceptances")}
    ros_messages = sum(t.get("camera_messages", 0) + t.get("goals", 0) for t in ros.values())
    result = {"cases_by_class": counts, "totals": totals,
              "ros": ros, "ros_messages_sent": ros_messages, "not_clean": failures,
              "peak_rss_mib": {"plan_4000x3000": plan_rss, "plan_4000x3000_exit_code": plan_code,
                               "detect_predict_30000x30000_header": header_rss, "detect_predict_30000x30000_exit_code": header_code,
                               "detect_predict_30000x30000_line": header_line}}
    _common.write_result("hostile", result, measured=set(result))  # every row measured again, even where it came out the same
    _common.write_section_of("hostile", section, "hostile.json")
    print(json.dumps({"totals": totals, "ros": ros, "peak_rss_mib": result["peak_rss_mib"]}, indent=1))


if __name__ == "__main__":
    main()
