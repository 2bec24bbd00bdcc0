"""A ROS 1 bridge (thesis §6.1.1): a binpick env served as a ROS action server, and a Gymnasium env
(``binpick/Ros-v0``) that drives it from anywhere on the ROS graph, so any binpick policy or trainer
can run a robot over ROS.

ROS comes from Debian (``python3-rospy python3-actionlib ...``), made visible to the venv by a
``.pth`` file that *appends* ``/usr/lib/python3/dist-packages`` (``scripts/setup.sh`` writes it when
it can install the packages).
"""

from __future__ import annotations

import os

from binpick.core.errors import BinpickError

DEBIAN_PACKAGES = ("python3-rospy", "python3-actionlib", "python3-rosmaster", "python3-genpy", "python3-genmsg",
                   "ros-std-msgs", "ros-actionlib-msgs", "python3-actionlib-msgs", "python3-std-msgs", "python3-sensor-msgs",
                   "ros-sensor-msgs", "python3-geometry-msgs", "ros-geometry-msgs", "python3-tf2-msgs", "python3-visualization-msgs",
                   "python3-roslaunch")


class RosUnavailable(BinpickError):
    """ROS 1's Python packages cannot be imported."""


class StalledPeer(BinpickError):
    """A peer answered and then stopped answering: threads blocked on it keep the process from exiting
    normally, so the command line leaves at once after saying so."""


def init_node_within(name: str, timeout: float, signals: bool = True) -> None:
    """``rospy.init_node`` that gives up after ``timeout`` seconds: rospy retries a master that answered
    once and then stalls for ever (its registration calls have no timeout). With ``signals``, Ctrl-C and
    SIGTERM shut the node down as rospy's own handlers would (those can only be installed from the main
    thread, and the node starts in another so that it can be waited for)."""
    import threading

    import rospy

    done, failures = threading.Event(), []

    def start() -> None:
        try:
            rospy.init_node(name, anonymous=True, disable_signals=True)
        except BaseException as error:  # noqa: BLE001 - handed to the caller's thread
            failures.append(error)
        finally:
            done.set()

    threading.Thread(target=start, name="binpick-init-node", daemon=True).start()
    if not done.wait(timeout):
        raise StalledPeer(f"the ROS master at {master_uri()} answered, then stopped answering: the node did not register "
                          f"within {timeout:g} s (restart the master, or give --master a working one)")
    if failures:
        raise failures[0]
    if signals:
        import signal

        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, lambda signum, frame: rospy.signal_shutdown(f"signal {signum}"))


def stop_timer(timer, wait: float = 3.0) -> None:
    """Stop a ``rospy.Timer`` and wait (at most ``wait`` seconds) for a callback it is running to end,
    so that nothing it publishes meets a topic rospy is closing."""
    import threading

    timer.shutdown()
    if timer is not threading.current_thread():
        timer.join(wait)


def ros_missing() -> str | None:
    """Why the bridge cannot run here, or None when it can."""
    try:
        import actionlib  # noqa: F401
        import genpy  # noqa: F401
        import rospy  # noqa: F401
        import tf2_msgs.msg  # noqa: F401
        import visualization_msgs.msg  # noqa: F401
    except ImportError as error:
        return (f"ROS 1 is not importable ({error.name}): install the Debian packages {' '.join(DEBIAN_PACKAGES)} "
                "and re-run scripts/setup.sh, which makes them visible to the venv")
    return None


def require_ros() -> None:
    reason = ros_missing()
    if reason:
        raise RosUnavailable(reason)


def local_ros_environment(master_uri: str, home: str | None = None) -> dict[str, str]:
    """Environment variables that keep a node on 127.0.0.1 and its logs in ``home``."""
    environment = {"ROS_MASTER_URI": master_uri, "ROS_IP": "127.0.0.1", "ROS_HOSTNAME": "127.0.0.1"}
    if home:
        environment |= {"ROS_HOME": home, "ROS_LOG_DIR": os.path.join(home, "log")}
    return environment


def master_uri() -> str:
    """The master this process's nodes use: ``$ROS_MASTER_URI``, or ROS's default."""
    return os.environ.get("ROS_MASTER_URI") or "http://localhost:11311/"


def check_master_uri(uri: str) -> str:
    """``http://HOST:PORT/`` with a port in 1..65535; anything else is one line."""
    from urllib.parse import urlsplit

    from binpick.core.errors import ConfigError

    try:
        parts = urlsplit(uri)
        port = parts.port
    except ValueError:
        parts, port = None, None
    if parts is None or parts.scheme != "http" or not parts.hostname or port is None or not 1 <= port <= 65535:
        raise ConfigError(f"ROS master URI must look like http://HOST:PORT/ (port 1-65535), got {uri!r}")
    return uri


def wait_for_master(uri: str, timeout: float) -> None:
    """Return once the master at ``uri`` answers; otherwise one line after ``timeout`` seconds.

    rospy itself retries an absent master forever (``init_node`` blocks), so every binpick node
    asks first."""
    import http.client
    import socket
    import time
    import xmlrpc.client
    from xml.parsers.expat import ExpatError

    check_master_uri(uri)
    deadline = time.monotonic() + timeout
    reason = "no answer"
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise BinpickError(f"no ROS master answered at {uri} within {timeout:g} s ({reason}): start one with "
                               "`binpick ros master` or `roscore`, or give --master")
        previous = socket.getdefaulttimeout()
        socket.setdefaulttimeout(max(0.1, min(remaining, 2.0)))
        try:
            answer = xmlrpc.client.ServerProxy(uri).getPid("/binpick")
            code = answer[0] if isinstance(answer, (list, tuple)) and len(answer) == 3 else None
            if code == 1:
                return
            raise BinpickError(f"the peer at {uri} answered getPid with {str(answer)[:60]!r}, not as a ROS master does: "
                               "give --master the URI of a running ROS master")
        except (OSError, xmlrpc.client.Error) as error:
            reason = getattr(error, "strerror", None) or type(error).__name__
        except (http.client.HTTPException, ExpatError, ValueError, TypeError) as error:  # it spoke, but no XML-RPC
            raise BinpickError(f"the peer at {uri} answered, but not as a ROS master does ({type(error).__name__}: "
                               f"{str(error)[:60]!r}): give --master the URI of a running ROS master") from None
        finally:
            socket.setdefaulttimeout(previous)
        time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))
