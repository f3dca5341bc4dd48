"""The five services, one module each; ``SERVICE_MODULES`` maps a service name to its module."""

SERVICE_MODULES = {
    "station": "fabric.services.station",
    "slicer": "fabric.services.slicer",
    "planner": "fabric.services.planner",
    "collision": "fabric.services.collision",
    "supervisor": "fabric.services.supervisor",
}
