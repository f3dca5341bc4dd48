"""G-code interpretation: any common slicer's dialect -> a columnar :class:`Toolpath`."""
from fabric.gcode.reader import ToolpathChunks, iter_blocks, parse_gcode, parse_gcode_file
from fabric.gcode.toolpath import (
                                   EV_BED_TEMP,
                                   EV_DWELL,
                                   EV_EXTRUDE,
                                   EV_FAN,
                                   EV_FW_RETRACT,
                                   EV_FW_UNRETRACT,
                                   EV_NOZZLE_TEMP,
                                   EVENT_NAMES,
                                   WAIT_ANY,
                                   WAIT_HEAT,
                                   WAIT_NONE,
                                   Toolpath,
)

__all__ = [
    "parse_gcode", "parse_gcode_file", "iter_blocks", "ToolpathChunks", "Toolpath", "EV_NOZZLE_TEMP", "EV_BED_TEMP",
    "EV_FAN", "EV_DWELL", "EV_FW_RETRACT", "EV_FW_UNRETRACT", "EV_EXTRUDE", "EVENT_NAMES",
    "WAIT_NONE", "WAIT_HEAT", "WAIT_ANY",
]
