"""Ray cluster addresses, checked before Ray starts (used by distributed RL and by data generation).

Locally ``ray.init()`` starts a private cluster on this machine, with every socket on 127.0.0.1;
``HOST:PORT`` or ``ray://HOST:PORT`` joins one started with ``ray start --head``.
"""

from __future__ import annotations

import contextlib
import os
import re
import socket
from collections.abc import Iterator

# With this set to 0, Ray treats the machine as a single-node setup and uses 127.0.0.1 for every
# address, instead of the machine's network address (its name says Windows/macOS; it works on Linux).
LOCAL_ONLY_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
_ADDRESS = re.compile(r"(ray://)?(?P<host>[A-Za-z0-9][A-Za-z0-9.\-]*|\[[0-9A-Fa-f:.]+\]):(?P<port>\d{1,5})")


def check_ray_address(address: str | None) -> str | None:
    """None (a private local cluster), ``auto``, or ``HOST:PORT`` / ``ray://HOST:PORT``; anything else
    is one line before Ray starts (Ray itself would retry a bad address for a long time)."""
    from binpick.core.errors import ConfigError

    if address is None or address == "auto":
        return address
    match = _ADDRESS.fullmatch(address)
    if match is None or not 1 <= int(match["port"]) <= 65535:
        raise ConfigError(f"--address must be HOST:PORT of a Ray head (e.g. 10.0.0.5:6379, from `ray start --head`), "
                          f"ray://HOST:PORT or auto; got {address!r}")
    return address


HTTP2_HELLO = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])  # preface + empty SETTINGS


def probe_ray_address(address: str, timeout: float = 5.0) -> None:
    """Fail in one line, within ``timeout``, when nothing at a cluster address answers: nothing
    listening, or a peer that accepts the connection and then stays silent (Ray would wait on it far
    longer). A Ray head's GCS and client server speak gRPC, which answers an HTTP/2 greeting at once."""
    from binpick.core.errors import ConfigError

    match = _ADDRESS.fullmatch(address)
    if match is None:
        return  # "auto": Ray finds the cluster itself
    host = match["host"].strip("[]")
    try:
        connection = socket.create_connection((host, int(match["port"])), timeout=timeout)
    except OSError as error:
        raise ConfigError(f"no Ray cluster answered at {address} within {timeout:.0f} s "
                          f"({error.strerror or type(error).__name__}): start one with `ray start --head`") from None
    with connection:
        try:
            connection.settimeout(timeout)
            connection.sendall(HTTP2_HELLO)
            answer = connection.recv(64)  # a gRPC server answers with an HTTP/2 SETTINGS frame (type 4) at once
        except TimeoutError:
            raise ConfigError(f"the peer at {address} accepted the connection but did not answer within {timeout:.0f} s: "
                              "not a Ray cluster (start one with `ray start --head`)") from None
        except OSError:
            return  # reset by a peer that spoke first (e.g. TLS): Ray itself will say what it is
    if answer and not (len(answer) >= 9 and answer[3] == 0x04):  # (a close without a word: Ray will say what it is)
        raise ConfigError(f"the peer at {address} answered, but not as a Ray cluster does (its first bytes "
                          f"{answer[:12]!r} are no HTTP/2 frame): start one with `ray start --head`, or give the head's HOST:PORT")


def start_ray(address: str | None, workers: int) -> bool:
    """Connect to ``address`` (checked and probed first) or start a private local cluster of
    ``workers`` CPUs on 127.0.0.1. Returns whether this call started Ray (and must shut it down)."""
    if address is None:
        os.environ[LOCAL_ONLY_ENV] = "0"  # for the processes Ray starts
    import ray

    if address is None:  # Ray read the variable when this process imported it, maybe before now
        from ray._private import ray_constants

        ray_constants.ENABLE_RAY_CLUSTER = False

    if address is not None:
        probe_ray_address(check_ray_address(address))
    if ray.is_initialized():
        return False
    env_vars = {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    try:
        if address is None:
            # a private cluster: every Ray process listens on, and announces, 127.0.0.1 only (without the node
            # address Ray takes the machine's network address and its servers listen on every interface);
            # gloo (data-parallel training) on the loopback interface too, whatever the host name resolves to.
            # Ray's processes inherit this process's environment: the variables are set here while Ray starts
            # (a runtime environment would start every worker through Ray's set-up process, ~1 s of CPU each)
            with _environment({**env_vars, "GLOO_SOCKET_IFNAME": "lo"}):
                ray.init(include_dashboard=False, log_to_driver=False, logging_level="ERROR", num_cpus=workers,
                         _node_ip_address="127.0.0.1")
        else:  # a cluster started elsewhere: its workers get the variables from a runtime environment
            ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="ERROR",
                     runtime_env={"env_vars": env_vars})
    except ConnectionError as error:  # --address auto with no cluster running here
        from binpick.core.errors import ConfigError

        raise ConfigError(f"no Ray cluster to join at --address {address}: start one with `ray start --head` "
                          f"(Ray: {str(error).splitlines()[0][:120]})") from None
    return True


@contextlib.contextmanager
def _environment(variables: dict[str, str]) -> Iterator[None]:
    """``variables`` in this process's environment for the block, the previous values back after it."""
    previous = {name: os.environ.get(name) for name in variables}
    os.environ.update(variables)
    try:
        yield
    finally:
        for name, value in previous.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
