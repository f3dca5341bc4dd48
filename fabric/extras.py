"""The parts of the install: what each extra of ``pyproject.toml`` brings, and the one line a command says when
it needs an extra that is not installed.

The base install (eclipse-zenoh, msgpack, numpy) carries ``fabric.wire``, ``fabric.schemas``, ``fabric.client``
and fabric-cli's client commands: enough for a monitor, or for the CLI against a running cell. ``services``
runs the services (``fabric-cli serve``, ``up``, ``cell``), ``tui`` the console, ``record`` Parquet recordings,
``plot`` and ``preview``, ``robot`` the station's Franka driver (``--robot franka:HOST``); ``all`` is the first
three. Entry points catch ``ModuleNotFoundError`` in one place and turn
it into ``missing_extra``'s ``ConfigError`` (``error [config]: fabric-cli up needs the services extra ...``).
"""
from __future__ import annotations

import importlib.util

from fabric.wire.errors import ConfigError

__all__ = ["EXTRAS", "extra_of", "missing_extra", "require"]

EXTRAS: dict[str, dict[str, str]] = {
    "services": {"pin": "pinocchio", "coal": "coal", "example-robot-data-loaders": "example_robot_data",
                 "trimesh": "trimesh", "shapely": "shapely", "manifold3d": "manifold3d",
                 "mapbox-earcut": "mapbox_earcut", "networkx": "networkx", "scipy": "scipy", "ruckig": "ruckig",
                 "tetgen": "tetgen"},
    "tui": {"textual": "textual"},
    "record": {"pyarrow": "pyarrow", "matplotlib": "matplotlib"},
    "robot": {"franky-control": "franky"},
}
"""extra -> {distribution: the top-level module it installs}, as ``[project.optional-dependencies]`` lists
them (a test keeps the two in step)."""

_ALSO = {"tomli": "services", "eigenpy": "services", "hppfcl": "services", "cmeel": "services",
         "rich": "tui", "mpl_toolkits": "record", "PIL": "record"}
"""Modules that come with an extra without being named in it: dependencies of its packages, tomli (Python
3.10 only), matplotlib's second top-level package."""

_EXTRA_OF = {module: extra for extra, dists in EXTRAS.items() for module in dists.values()} | _ALSO


def extra_of(module: str) -> str | None:
    """The extra that installs ``module`` (a dotted name; its top level counts), or None (base or unknown)."""
    return _EXTRA_OF.get(module.split(".")[0])


def missing_extra(exc: ModuleNotFoundError, what: str) -> ConfigError | None:
    """The error to report when ``what`` (e.g. ``fabric-cli up``) failed on ``exc``, if an extra would bring
    the missing module; None when it is no module of an extra (a real bug: let it raise)."""
    module = (exc.name or "").split(".")[0]
    extra = extra_of(module)
    if extra is None:
        return None
    return ConfigError(f"{what} needs the {extra} extra ({module} is not installed): "
                       f"pip install 'am-fabric[{extra}]'", field="extras", value=extra, module=module)


def require(extra: str) -> None:
    """Raise ``ModuleNotFoundError`` (for ``missing_extra``) unless every package of ``extra`` is installed;
    looks them up without importing them. For commands that would only fail later, in another process
    (``fabric-cli up`` starts the services as children)."""
    for module in EXTRAS[extra].values():
        if importlib.util.find_spec(module) is None:
            raise ModuleNotFoundError(f"No module named {module!r}", name=module)
