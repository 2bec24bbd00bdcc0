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
import contextlib
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

def _receive(connection: socket.socket) -> tuple[dict, list[int]]:
    """One request: an 8-byte length, the JSON (env and argv), the three stream fds with its first bytes."""
    data, fds, _, _ = socket.recv_fds(connection, 1 << 16, 3)
    if len(data) < 8 or len(fds) != 3:
        raise OSError("a short request")
    size = int(data[:8])
    data = data[8:]
    while len(data) < size:
        more = connection.recv(size - len(data))
        if not more:
            raise OSError("a short request")
        data += more
    return json.loads(data), fds


def serve(listener: socket.socket, parent: int) -> tuple[dict, socket.socket] | None:
    """Fork a child for each request; once the child has exited, answer the request's connection with its
    exit status (the child itself sends its pid first, when it is ready for signals). Returns, only in a
    child, its request and connection; returns None when the test process that started the server is gone."""
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
            fds: list[int] = []
            try:  # a bad or broken request costs its own run only, never the server
                request, fds = _receive(connection)
                pid = os.fork()
            except (OSError, ValueError):
                for fd in fds:
                    os.close(fd)
                connection.close()
                continue
            if pid == 0:
                signal.set_wakeup_fd(-1)
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                for fd in (wake_read, wake_write):
                    os.close(fd)
                listener.close()
                for other in waiting.values():
                    other.close()
                request["fds"] = fds
                return request, connection
            for fd in fds:
                os.close(fd)
            waiting[pid] = connection
        for pid in list(waiting):  # (only the requests' children: nothing else of this process is reaped)
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                connection = waiting.pop(pid)
                try:
                    connection.sendall(f"{os.waitstatus_to_exitcode(status)}\n".encode())
                except OSError:
                    pass
                connection.close()
    return None


def become(request: dict, connection: socket.socket) -> None:
    """In the fork: take the request's streams, folder, environment, signals and argv, as a fresh
    ``python -c`` would have them; then tell the caller this process's pid."""
    if request["new_session"]:
        os.setsid()
    for target, fd in zip((0, 1, 2), request["fds"]):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    for name, value in request["preloaded_environment"].items():  # what the preloaded imports set, as they would have
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    signal.signal(signal.SIGINT, signal.SIG_IGN if request["sigint_ignored"] else signal.default_int_handler)
    sys.argv = ["-c", *request["args"]]
    sys.path[:] = ["", *(p for p in sys.path if p and p != os.path.dirname(os.path.abspath(__file__)))]
    sys.stdout.reconfigure(line_buffering=os.isatty(1))  # as an interpreter started on these streams has it
    connection.sendall(f"{os.getpid()}\n".encode())
    connection.close()


def server_main(path: str) -> None:
    import importlib

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C to the test run is the test process's to handle
    before = dict(os.environ)
    for name in PRELOAD:
        importlib.import_module(name)
    # (the only thread besides this one is OpenBLAS's pool, started by numpy's import: it stops and restarts
    # its threads around a fork itself; torch's and Mesa's pools start on first use, in the forks)
    changed = {k: os.environ.get(k) for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k)}
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(64)
    print("ready " + json.dumps(changed), flush=True)
    served = serve(listener, os.getppid())
    if served is None:
        os._exit(0)
    become(*served)
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
        # in this process's group: a Ctrl-C to the test run reaches the forks as it would plain subprocesses
        self.process = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        env=self.env)
        line = self.process.stdout.readline().decode()
        if not line.startswith("ready "):
            self.process.kill()
            raise RuntimeError(f"the CLI server did not start (exit code {self.process.wait()})")
        self.preloaded_environment: dict[str, str | None] = json.loads(line[6:])  # what its imports set (cv2: LD_LIBRARY_PATH)
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
        """The variables ``env`` has otherwise than this server (as the preloaded imports left it), beside those
        read at call time."""
        def theirs(name: str) -> str | None:
            return self.preloaded_environment[name] if name in self.preloaded_environment else self.env.get(name)

        return {k for k in set(env) | set(self.env) | set(self.preloaded_environment)
                if env.get(k) != self.env.get(k) and env.get(k) != theirs(k)} - set(READ_AT_CALL_TIME)

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
        if stdin == subprocess.PIPE:
            raise ValueError("a forked CLI takes no input pipe")
        self.args = [*CLI, *map(str, args)]
        self.returncode: int | None = None
        self.stdout = self.stderr = None
        request = {"args": [str(a) for a in args], "cwd": os.path.abspath(os.fspath(cwd or os.getcwd())),
                   "env": dict(env or os.environ), "new_session": start_new_session,
                   "sigint_ignored": not ctrl_c and signal.getsignal(signal.SIGINT) == signal.SIG_IGN,
                   "preloaded_environment": server.preloaded_environment}
        fds: list[int] = []
        readers: list[int | None] = []
        try:
            for spec, default in ((stdin, 0), (stdout, 1), (stderr, 2)):
                fd, reader = _stream(spec, default)
                fds.append(os.dup(fds[1]) if fd == -1 else fd)
                readers.append(reader)
            self._connection = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self._connection.connect(server.path)
            message = json.dumps(request).encode()
            socket.send_fds(self._connection, [b"%08d" % len(message) + message[:4096]], fds)
            self._connection.sendall(message[4096:])
        except BaseException:
            for fd in readers:
                if fd is not None:
                    os.close(fd)
            raise
        finally:
            for fd in fds:
                os.close(fd)
        self._answer = self._connection.makefile("rb")
        line = self._answer.readline()  # the fork's own pid, sent once it has taken its signals and session
        if not line.strip():
            raise RuntimeError("the CLI server did not start the process (it died or refused the request)")
        self.pid = int(line)
        mode = {"encoding": "utf-8"} if text else {}
        if readers[1] is not None:
            self.stdout = open(readers[1], "r" + ("" if text else "b"), **mode)
        if readers[2] is not None:
            self.stderr = open(readers[2], "r" + ("" if text else "b"), **mode)

    def poll(self) -> int | None:
        if self.returncode is None and select.select([self._connection], [], [], 0)[0]:
            self._read_status()
        return self.returncode

    def _read_status(self) -> None:
        line = self._answer.readline()
        self._answer.close()
        self._connection.close()
        if not line.strip():
            raise RuntimeError(f"the CLI server died while {self.args[3:5]} ran (pid {self.pid})")
        self.returncode = int(line)

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            if not select.select([self._connection], [], [], timeout)[0]:
                raise subprocess.TimeoutExpired(self.args, timeout)
            self._read_status()
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:  # (an ended process's pid may already be another's)
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple:
        """Both streams read to their end in this thread (as Popen does), then the exit status."""
        import selectors

        deadline = None if timeout is None else time.monotonic() + timeout
        chunks = {stream: [] for stream in (self.stdout, self.stderr) if stream is not None and not stream.closed}
        with selectors.DefaultSelector() as selector:
            for stream in chunks:
                selector.register(stream.fileno(), selectors.EVENT_READ, stream)
            while selector.get_map():
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise subprocess.TimeoutExpired(self.args, timeout)
                for key, _ in selector.select(left):
                    data = os.read(key.fd, 1 << 16)
                    if data:
                        chunks[key.data].append(data)
                    else:
                        selector.unregister(key.fd)
        self.wait(None if deadline is None else max(0.0, deadline - time.monotonic()))
        results = {}
        for stream, parts in chunks.items():
            data = b"".join(parts)
            results[stream] = data.decode(stream.encoding) if hasattr(stream, "encoding") else data
            stream.close()
        return results.get(self.stdout), results.get(self.stderr)

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
