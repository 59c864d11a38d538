"""One environment module per registered version, `scenarios.<family>_v<N>`, made from the
registry at `import scenarios`, as PettingZoo's own packages re-export each version:

    from scenarios import halting_car_v3      # or: import scenarios.halting_car_v3
    env = halting_car_v3.parallel_env()       # env() for the AEC API, raw_env the class
    vec = halting_car_v3.vector_env(num_envs=64)

The modules are registered in `sys.modules`, so `import`, `pickle` and `pydoc` find them like
files. Each version's environment class (`raw_env`, also under its own name, e.g.
`HaltingCarV3Env`) is built on first use, with its manual (`scenarios.manual`) as docstring, so
`import scenarios` does not import PettingZoo.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from types import ModuleType
from typing import Any

from scenarios.registry import FAMILIES, VERSIONS
from scenarios.versioning import ScenarioVersion

EXPORTS = ("parallel_env", "env", "raw_env", "vector_env")


def class_name(version: ScenarioVersion) -> str:
    """The environment class's name: "halting_car", 3 -> "HaltingCarV3Env"."""
    family = "".join(part.capitalize() for part in version.family.split("_"))
    return f"{family}V{version.number}Env"


class EnvironmentModule(ModuleType):
    """`scenarios.<version>`: `parallel_env`, `env`, `raw_env`, `vector_env` of one version;
    `family` is its family's versions (the manual's version history)."""

    def __init__(self, version: ScenarioVersion, family: Sequence[ScenarioVersion]) -> None:
        super().__init__(
            f"scenarios.{version.name}",
            f"{version.title} v{version.number} as a PettingZoo environment: `parallel_env()`, "
            f"`env()` (AEC), `raw_env` (the class, whose docstring is the user manual: "
            f"`help(scenarios.{version.name}.raw_env)`) and `vector_env(num_envs)` "
            "(`scenarios.vector_env`).",
        )
        self.version = version
        self.history = [earlier for earlier in family if earlier.number <= version.number]

    def __getattr__(self, name: str) -> Any:  # called only for names not built yet
        if name in (*EXPORTS, class_name(self.version)):
            self._build()
            return self.__dict__[name]
        raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")

    def __dir__(self) -> list[str]:
        return sorted({*super().__dir__(), *EXPORTS, class_name(self.version)})

    def _build(self) -> None:
        from pettingzoo.utils.conversions import parallel_to_aec

        from scenarios.env import ScenarioParallelEnv, env_metadata
        from scenarios.manual import environment_manual
        from scenarios.vector_env import ScenarioVectorEnv

        version = self.version
        name = class_name(version)
        env_class = type(
            name,
            (ScenarioParallelEnv,),
            {
                "__doc__": environment_manual(version, self.history),
                "__module__": self.__name__,
                "__qualname__": name,
                "version": version,
                "metadata": env_metadata(version),
            },
        )

        def parallel_env(**kwargs: Any) -> ScenarioParallelEnv:
            return env_class(**kwargs)

        def env(**kwargs: Any):
            return parallel_to_aec(env_class(**kwargs))

        def vector_env(num_envs: int, **kwargs: Any) -> ScenarioVectorEnv:
            return ScenarioVectorEnv(version, num_envs, **kwargs)

        parallel_env.__doc__ = f"The {version.name} parallel environment (arguments: raw_env)."
        env.__doc__ = f"{version.name} with the AEC API (agents act in turn, `parallel_to_aec`)."
        vector_env.__doc__ = (
            f"{version.name} with `num_envs` scenes stepped at once (`scenarios.vector_env`)."
        )
        for function in (parallel_env, env, vector_env):
            function.__module__ = self.__name__
        self.__dict__.update(
            {
                name: env_class,
                "raw_env": env_class,
                "parallel_env": parallel_env,
                "env": env,
                "vector_env": vector_env,
            }
        )


def install(package: dict[str, Any]) -> dict[str, EnvironmentModule]:
    """Make every version's module, register it in `sys.modules` and in `package` (the
    `scenarios` namespace); returns them by version name."""
    modules = {}
    for name, version in VERSIONS.items():
        module = sys.modules.get(f"scenarios.{name}")
        if not isinstance(module, EnvironmentModule):
            module = EnvironmentModule(version, FAMILIES[version.family])
            sys.modules[module.__name__] = module
        package[name] = modules[name] = module
    return modules
