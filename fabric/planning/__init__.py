"""Planning: G-code -> a verified robot program (approach, print, return home) and its exports.

The names below are imported on first use, so that a light submodule (``post.atomic``,
``memory``) does not pull in the planner, the G-code reader and the kinematics.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fabric.planning.options import PlanOptions
    from fabric.planning.planner import plan_gcode, plan_gcode_file, plan_toolpath
    from fabric.planning.report import PlanResult, PlanStats, Reachability

__all__ = ["PlanOptions", "plan_gcode", "plan_gcode_file", "plan_toolpath", "PlanResult", "PlanStats",
           "Reachability"]

_HOME = {"PlanOptions": "options", "plan_gcode": "planner", "plan_gcode_file": "planner",
         "plan_toolpath": "planner", "PlanResult": "report", "PlanStats": "report", "Reachability": "report"}


def __getattr__(name: str) -> Any:
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)
