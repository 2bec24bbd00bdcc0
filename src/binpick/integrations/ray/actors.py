"""Ray actors that Ray restarts when their process dies (thesis §6.1's distributed simulators, in place of
ROS multimaster): the pool under A3C's rollout workers (:mod:`binpick.integrations.ray.a3c`) and the RL
simulators of :mod:`binpick.integrations.ray.envs`.

Locally :func:`binpick.core.cluster.start_ray` starts a private cluster on 127.0.0.1; an address (``HOST:6379``,
``ray://...``) joins a cluster started with ``ray start --head`` (docs/guide/cluster.md).
"""

from __future__ import annotations

import time
from typing import Any

from binpick.core.cluster import start_ray


def raise_if_it_never_started(error: Exception, what: str) -> None:
    """An actor whose ``__init__`` raised is dead for good (Ray does not restart it): a
    :class:`~binpick.core.errors.WorkerError` naming the cause at once, instead of waiting for restarts."""
    from binpick.core.errors import WorkerError

    if getattr(error, "actor_init_failed", False):
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
        cause = next((line for line in reversed(lines) if "Error" in line.split(":")[0]), lines[-1] if lines else "")
        raise WorkerError(f"{what} could not start on Ray: {cause}") from None


class RestartingActors:
    """Ray actors of one class that Ray restarts when their process dies. The caller keeps them busy
    (:meth:`start`, :meth:`idle`) and takes results as tasks end (:meth:`next_result`); a task lost with
    its worker is reported, and a death counted once."""

    def __init__(self, actor_class: type, arguments: list[tuple], address: str | None = None) -> None:
        from binpick.core.errors import ConfigError

        if not arguments:
            raise ConfigError("workers must be at least 1, got 0")
        self.owns_ray = start_ray(address, len(arguments))  # a private local cluster stays on 127.0.0.1
        import ray

        try:
            cpus = ray.cluster_resources().get("CPU", 0)
            if cpus < len(arguments):  # they would wait for CPUs for ever
                raise ConfigError(f"{len(arguments)} Ray actors need a CPU each; the cluster has {cpus:g}")
            remote = ray.remote(num_cpus=1, max_restarts=-1, max_task_retries=0)(actor_class)
            self.actors = [remote.remote(*args) for args in arguments]
        except BaseException:
            if self.owns_ray:
                ray.shutdown()
            raise
        self.in_flight: dict[Any, int] = {}
        self.recovering: set[int] = set()  # workers whose process died and is being restarted
        self.deaths = 0  # worker processes that died: each lost its task in flight and was restarted

    def pids(self, timeout: float = 60.0) -> list[int]:
        """Process ids of the workers (waits for restarting ones)."""
        import ray
        from ray.exceptions import ActorUnavailableError, RayActorError

        deadline = time.monotonic() + timeout
        while True:
            try:
                return ray.get([actor.pid.remote() for actor in self.actors])
            except (RayActorError, ActorUnavailableError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)

    def start(self, index: int, ref: Any) -> None:
        """A task (its object ref) now runs on worker ``index``."""
        self.in_flight[ref] = index

    def idle(self) -> list[int]:
        """Workers with no task running."""
        busy = set(self.in_flight.values())
        return [index for index in range(len(self.actors)) if index not in busy]

    def next_result(self, timeout: float | None = None) -> tuple[int, Any, bool]:
        """The next task to end: ``(worker index, result, True)``, or ``(index, None, False)`` when the
        worker died with it (Ray restarts the worker; a death is counted once however many tasks it
        loses while restarting). No task ending within ``timeout`` seconds is a :class:`TimeoutError`."""
        import ray
        from ray.exceptions import ActorUnavailableError, RayActorError

        ready, _ = ray.wait(list(self.in_flight), num_returns=1, timeout=timeout)
        if not ready:
            raise TimeoutError(f"no worker finished a task within {timeout:.0f} s")
        index = self.in_flight.pop(ready[0])
        try:
            result = ray.get(ready[0])
        except (RayActorError, ActorUnavailableError) as error:
            raise_if_it_never_started(error, f"worker {index}")
            if index not in self.recovering:
                self.deaths += 1
                self.recovering.add(index)
            time.sleep(0.2)
            return index, None, False
        self.recovering.discard(index)
        return index, result, True

    def close(self) -> None:
        import ray

        for actor in self.actors:
            ray.kill(actor, no_restart=True)
        self.actors, self.in_flight = [], {}
        if self.owns_ray:  # we started the local cluster: stop it too
            ray.shutdown()
