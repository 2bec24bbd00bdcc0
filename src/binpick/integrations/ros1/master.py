"""A ROS master on 127.0.0.1 (``rosmaster --core``), started and stopped from Python, with ``/run_id``
set as ``roscore`` sets it (``roslaunch --wait`` waits for it)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
import xmlrpc.client

from binpick.core.errors import BinpickError
from binpick.integrations.ros1 import local_ros_environment, require_ros


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _die_with_parent() -> None:
    """In the child before exec: Linux sends it SIGTERM when the process that started it dies, even
    by ``kill -9``, so a master never outlives the command that owns it."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass  # not Linux: SIGTERM/Ctrl-C of the owner still stops the master (see stop())


class RosMaster:
    """``with RosMaster() as master:`` runs a master on a free port; ``master.uri`` names it."""

    def __init__(self, port: int | None = None, timeout: float = 15.0) -> None:
        require_ros()
        self.port = port or free_port()
        self.uri = f"http://127.0.0.1:{self.port}/"
        self.home = tempfile.mkdtemp(prefix="binpick-ros-")
        self.environment = {**os.environ, **local_ros_environment(self.uri, self.home)}
        self.process = subprocess.Popen([sys.executable, "-c", "import rosmaster; rosmaster.rosmaster_main()", "--core",
                                         "-p", str(self.port), "-w", "2"], env=self.environment,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, preexec_fn=_die_with_parent)
        try:
            self._wait_until_it_answers(timeout)
        except BaseException:  # Ctrl-C or SIGTERM while it starts, too: no master outlives its owner
            self.stop()
            raise

    def _wait_until_it_answers(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise BinpickError(f"rosmaster exited: {self.process.stderr.read().decode(errors='replace').strip()[-300:]}")
            previous = socket.getdefaulttimeout()
            socket.setdefaulttimeout(max(0.1, min(deadline - time.monotonic(), 2.0)))  # a silent peer on the port: no hang
            try:
                master = xmlrpc.client.ServerProxy(self.uri)
                master.getPid("/binpick")
                master.setParam("/binpick", "/run_id", str(uuid.uuid1()))  # what roscore sets; roslaunch reads it
                return
            except (OSError, xmlrpc.client.Error):
                time.sleep(0.05)
            finally:
                socket.setdefaulttimeout(previous)
        raise BinpickError(f"rosmaster did not answer on {self.uri} within {timeout:.0f} s")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)  # what rosmaster --core waits for
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()

    def __enter__(self) -> "RosMaster":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
