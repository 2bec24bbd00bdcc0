"""``binpick`` CLI processes for the tests, forked from a server that imported torch, MuJoCo and the rest once.

A test that is about the process itself (Ctrl-C, a kill, exit codes, a full disk, what reaches stdout)
needs a real process; starting one as ``python -c "from binpick.cli import main; main()"`` costs 3-4 s of
CPU on a small machine, nearly all of it importing torch, MuJoCo, Gymnasium-Robotics and friends. Here a
server process (one per test process, started on first use) imports those once; each CLI run is a fork of
it that takes the caller's argv, working folder, environment, standard streams (passed as file
descriptors), SIGINT disposition and session, then runs binpick's entry point as ``python -c`` would,
interpreter exit included (atexit handlers, non-daemon threads, an uncaught KeyboardInterrupt ending the
process by SIGINT). binpick itself is imported in the fork, after the environment is set.

:func:`popen` and :func:`run` take the arguments of :class:`subprocess.Popen` / :func:`subprocess.run`
that the tests use. A call whose environment differs from the server's in a variable a preloaded module
reads when it is imported (anything but :data:`READ_AT_CALL_TIME`), or that needs another interpreter or
a ``preexec_fn``, runs as a plain subprocess instead: the fork would otherwise inherit the server's
import-time state.
"""

from __future__ import annotations

import atexit
import json
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

CLI = [sys.executable, "-c", "from binpick.cli import main; main()"]
# What the server imports: the heavy third-party modules binpick's commands use (never binpick itself)
PRELOAD = ("numpy", "torch", "torch.nn", "torch.utils.tensorboard", "cv2", "PIL.Image", "safetensors.torch", "yaml",
           "rich.console", "typer", "gymnasium", "mujoco", "gymnasium_robotics", "stable_baselines3", "gpytorch",
           "matplotlib", "pycocotools.coco")
# Variables that may differ between the server and a run: nothing preloaded reads them at import time
READ_AT_CALL_TIME = ("COLUMNS", "LINES", "TERM", "NO_COLOR", "FORCE_COLOR", "PYTEST_CURRENT_TEST", "ROS_HOME", "ROS_LOG_DIR",
                     "ROS_MASTER_URI", "ROS_IP", "ROS_HOSTNAME", "BINPICK_SPAWN_WORKERS",
                     "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "KMP_DUPLICATE_LIB_OK", "XDG_CACHE_HOME")


# --- the server ------------------------------------------------------------------------------------------

def serve(listener: socket.socket, parent: int) -> dict | None:
    """Fork a child for each request; answer each request's connection with the child's pid, then its exit
    status. Returns (only in a child) the request the child is to run; returns None when the test process
    that started the server is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the test run is the test process's to handle
    wake_read, wake_write = os.pipe()  # a child's end wakes the loop (SIGCHLD through Python's wakeup fd)
    os.set_blocking(wake_write, False)
    signal.set_wakeup_fd(wake_write)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    waiting: dict[int, socket.socket] = {}  # child pid -> its request's connection
    while os.getppid() == parent:
        ready, _, _ = select.select([listener, wake_read], [], [], 1.0)
        if wake_read in ready:
            os.read(wake_read, 4096)
        if listener in ready:
            connection, _ = listener.accept()
            message, fds, _, _ = socket.recv_fds(connection, 1 << 20, 3)
            request = json.loads(message)
            pid = os.fork()
            if pid == 0:
                signal.set_wakeup_fd(-1)
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                os.close(wake_read)
                os.close(wake_write)
                listener.close()
                connection.close()
                for other in waiting.values():
                    other.close()
                request["fds"] = fds
                return request
            for fd in fds:
                os.close(fd)
            connection.sendall(f"{pid}\n".encode())
            waiting[pid] = connection
        while waiting:
            pid, status = os.waitpid(-1, os.WNOHANG)
            if pid == 0:
                break
            connection = waiting.pop(pid, None)
            if connection is not None:
                try:
                    connection.sendall(f"{os.waitstatus_to_exitcode(status)}\n".encode())
                except OSError:
                    pass
                connection.close()
    return None


def become(request: dict) -> None:
    """In the fork: take the request's streams, folder, environment, signals and argv, as a fresh
    ``python -c`` would have them."""
    if request["new_session"]:
        os.setsid()
    for target, fd in zip((0, 1, 2), request["fds"]):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    signal.signal(signal.SIGINT, signal.SIG_IGN if request["sigint_ignored"] else signal.default_int_handler)
    sys.argv = ["-c", *request["args"]]
    sys.path[:] = ["", *(p for p in sys.path if p and p != os.path.dirname(os.path.abspath(__file__)))]


def server_main(path: str) -> None:
    import importlib

    for name in PRELOAD:
        importlib.import_module(name)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(64)
    print("ready", flush=True)
    request = serve(listener, os.getppid())
    if request is None:
        os._exit(0)
    become(request)
    from binpick.cli import main

    main()


# --- the client ------------------------------------------------------------------------------------------

class _Server:
    """The server of this test process, started on first use and stopped when the process ends."""

    def __init__(self) -> None:
        self.folder = tempfile.mkdtemp(prefix="binpick-cli-")
        self.path = os.path.join(self.folder, "socket")
        self.env = dict(os.environ)
        code = f"import sys; sys.path.insert(0, {os.path.dirname(os.path.abspath(__file__))!r}); " \
               f"import cli_zygote; cli_zygote.server_main({self.path!r})"
        self.process = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        env=self.env, start_new_session=True)
        line = self.process.stdout.readline()
        if line.strip() != b"ready":
            raise RuntimeError(f"the CLI server did not start (exit code {self.process.wait()})")
        atexit.register(self.stop)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        try:
            os.unlink(self.path)
            os.rmdir(self.folder)
        except OSError:
            pass

    def differing(self, env: dict[str, str]) -> set[str]:
        """The variables ``env`` has otherwise than this server, beside those read at call time."""
        return {k for k in set(env) | set(self.env) if env.get(k) != self.env.get(k)} - set(READ_AT_CALL_TIME)

    def serves(self, env: dict[str, str]) -> bool:
        return self.process.poll() is None and not self.differing(env)


_server: _Server | None = None
_lock = threading.Lock()


def _the_server() -> _Server:
    global _server
    with _lock:
        if _server is None or _server.process.poll() is not None:
            _server = _Server()
        return _server


def _stream(spec, default_fd: int) -> tuple[int, int | None]:
    """(the fd the child gets, the parent's read end or None) for a Popen stream argument."""
    if spec == subprocess.PIPE:
        read, write = os.pipe()
        return write, read
    if spec == subprocess.DEVNULL:
        return os.open(os.devnull, os.O_RDWR), None
    if spec is None:
        return os.dup(default_fd), None
    if spec == subprocess.STDOUT:
        return -1, None
    return os.dup(spec if isinstance(spec, int) else spec.fileno()), None


class ForkedCLI:
    """The part of :class:`subprocess.Popen` the tests use, for a CLI process forked from the server."""

    def __init__(self, args, *, cwd=None, env=None, stdin=None, stdout=None, stderr=None, text=False,
                 start_new_session=False, ctrl_c=False, server: _Server) -> None:
        self.args = [*CLI, *map(str, args)]
        fd_in, _ = _stream(stdin if stdin is not None else subprocess.DEVNULL, 0)
        fd_out, self._out = _stream(stdout, 1)
        fd_err, self._err = _stream(stderr, 2)
        if fd_err == -1:
            fd_err = os.dup(fd_out)
        request = {"args": [str(a) for a in args], "cwd": os.fspath(cwd or os.getcwd()), "env": dict(env or os.environ),
                   "new_session": start_new_session,
                   "sigint_ignored": not ctrl_c and signal.getsignal(signal.SIGINT) == signal.SIG_IGN}
        self._connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._connection.connect(server.path)
            socket.send_fds(self._connection, [json.dumps(request).encode()], [fd_in, fd_out, fd_err])
        finally:
            for fd in (fd_in, fd_out, fd_err):
                os.close(fd)
        self._answer = self._connection.makefile("rb")
        self.pid = int(self._answer.readline())
        mode = {"encoding": "utf-8", "errors": "replace"} if text else {}
        self.stdout = open(self._out, "r" + ("" if text else "b"), **mode) if self._out is not None else None
        self.stderr = open(self._err, "r" + ("" if text else "b"), **mode) if self._err is not None else None
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None and select.select([self._connection], [], [], 0)[0]:
            self._read_status()
        return self.returncode

    def _read_status(self) -> None:
        line = self._answer.readline()
        self.returncode = int(line) if line.strip() else -signal.SIGKILL  # the server itself was killed
        self._connection.close()

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            if not select.select([self._connection], [], [], timeout)[0]:
                raise subprocess.TimeoutExpired(self.args, timeout)
            self._read_status()
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:
            os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple:
        """Both streams read to their end (each by a thread, as Popen does), then the exit status."""
        results: dict[str, object] = {}
        readers = [threading.Thread(target=lambda n=name, s=stream: results.__setitem__(n, s.read()), daemon=True)
                   for name, stream in (("out", self.stdout), ("err", self.stderr)) if stream is not None]
        for reader in readers:
            reader.start()
        deadline = None if timeout is None else time.monotonic() + timeout
        for reader in readers:
            reader.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
            if reader.is_alive():
                raise subprocess.TimeoutExpired(self.args, timeout)
        self.wait(None if deadline is None else max(0.0, deadline - time.monotonic()))
        for stream in (self.stdout, self.stderr):
            if stream is not None:
                stream.close()
        return results.get("out"), results.get("err")

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        for stream in (self.stdout, self.stderr):
            if stream is not None:
                stream.close()
        self.wait()


def popen(args, *, env=None, preexec_fn=None, ctrl_c: bool = False, **options):
    """``binpick ARGS`` as ``subprocess.Popen([*CLI, *ARGS], ...)`` would start it, forked from the server
    when it can be. ``ctrl_c``: SIGINT reaches the CLI as in a terminal's foreground job even when this
    test process ignores it (a suite started in the background)."""
    env = dict(os.environ if env is None else env)
    if preexec_fn is None and os.environ.get("BINPICK_TESTS_SPAWN_CLI") != "1":
        server = _the_server()
        if server.serves(env):
            return ForkedCLI(args, env=env, ctrl_c=ctrl_c, server=server, **options)
        _log(f"spawned (environment differs: {sorted(server.differing(env))}): {args[:3]}")
    else:
        _log(f"spawned (preexec_fn or BINPICK_TESTS_SPAWN_CLI): {args[:3]}")
    if ctrl_c and preexec_fn is None:
        preexec_fn = _default_sigint
    return subprocess.Popen([*CLI, *map(str, args)], env=env, preexec_fn=preexec_fn, **options)


def _log(line: str) -> None:
    """``BINPICK_TESTS_CLI_LOG=FILE``: which runs were not forked, and why (to see what the server saves)."""
    if os.environ.get("BINPICK_TESTS_CLI_LOG"):
        with open(os.environ["BINPICK_TESTS_CLI_LOG"], "a") as log:
            log.write(line + "\n")


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run(args, *, capture_output: bool = False, timeout: float | None = None, input=None, **options):
    """``binpick ARGS`` as ``subprocess.run([*CLI, *ARGS], ...)`` would run it: a CompletedProcess."""
    if input is not None:
        raise ValueError("run() here takes no input")
    if capture_output:
        options.update(stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    with popen(args, **options) as process:
        try:
            out, err = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            raise
    return subprocess.CompletedProcess(process.args, process.returncode, out, err)
