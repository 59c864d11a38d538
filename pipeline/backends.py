"""Where a pipeline's jobs run: local processes (pipeline.pool) or Ray tasks
(pipeline.ray_backend), behind one `Runner.map`."""

from __future__ import annotations

import contextlib
import sys

from tqdm import tqdm

from pipeline.pool import run_parallel

BACKENDS = ("local", "ray")  # where jobs run: processes here, or Ray tasks (pipeline.ray_backend)


class Runner(contextlib.ExitStack):
    """Runs a function over items on a backend: `jobs` local processes, or Ray tasks of
    `cpus_per_task` CPUs each, retried `retries` times if their worker dies (on a local Ray
    instance of `jobs` CPUs, or the cluster at `address`). A context manager: Ray is started on
    first use and shut down on leaving."""

    def __init__(
        self,
        backend: str,
        jobs: int,
        address: str | None = None,
        cpus_per_task: float = 1,
        retries: int = 1,
    ) -> None:
        super().__init__()
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        if backend == "ray":
            from pipeline.ray_backend import require_ray

            require_ray()  # fail before any work, even if the cache has everything
        self.backend, self.jobs, self.address = backend, jobs, address
        self.cpus_per_task, self.retries = cpus_per_task, retries
        self.connected = False

    def map(self, function, items: list, desc: str, deadline: float | None = None) -> list:
        """function(item) per item, results in item order: None for an item not started
        before `deadline`; on Ray, a `TaskFailed` for one that raised or whose worker died
        twice (locally an exception propagates)."""
        if not items:
            return []
        if self.backend == "local":
            return run_parallel(function, items, self.jobs, desc, deadline)
        from pipeline.ray_backend import map_settled, ray_session

        if not self.connected:
            self.enter_context(ray_session(self.address, self.jobs))
            self.connected = True
        bar = tqdm(total=len(items), desc=desc, unit="job", file=sys.stderr, dynamic_ncols=True)
        with bar:
            return map_settled(
                function,
                items,
                num_cpus=self.cpus_per_task,
                max_retries=self.retries,
                deadline=deadline,
                on_result=lambda result: bar.update(),
            )
