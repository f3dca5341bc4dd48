"""Planning: G-code -> a verified robot program (approach, print, return home) and its exports."""
from fabric.planning.options import PlanOptions
from fabric.planning.planner import plan_gcode, plan_gcode_file, plan_toolpath
from fabric.planning.report import PlanResult, PlanStats, Reachability

__all__ = ["PlanOptions", "plan_gcode", "plan_gcode_file", "plan_toolpath", "PlanResult", "PlanStats",
           "Reachability"]
