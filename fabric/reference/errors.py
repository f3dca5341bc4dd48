"""The details each error code carries, as the reference states them (``fabric.wire.errors`` raises them)."""
from __future__ import annotations

__all__ = ["ERROR_DETAILS"]

ERROR_DETAILS: dict[str, str] = {
    "internal": "`service`, `command`: where an unexpected failure happened (a bug; the service is degraded).",
    "bad_request": "what was wrong, e.g. `file`.",
    "decode": "`reason` (one of @@decode_reasons@@), `expected` (the message type asked for); with `reason` `type`: "
              "`got` (the `_t` received); with `reason` `version`: `got` (the `_v` received), `supported` (the "
              "newest version the receiver knows).",
    "validation": "`field` (the dotted path of the field; `\"\"`: the whole message), `schema` (the message type: "
                  "the request's when the service's own check of it refused it), always.",
    "gcode": "`line` (1-based), `text`.",
    "mesh": "`file`, `reason` (`empty`, `format`, `truncated`, `open`, ...).",
    "profile": "`key` (the profile entry at fault), `value`.",
    "config": "`field` (``section.key``), `value`.",
    "placement": "what does not fit, e.g. `plate_size_mm`, `center_xy_mm`.",
    "unreachable": "`reason` (one of @@unreachable@@), `gcode_line` (-1: not from G-code), and where known `row`, "
                   "`joint` (0-based), `xyz_mm`, `probe`.",
    "cold_extrusion": "`reason` (one of @@cold@@), `gcode_line`, `row`, `nozzle_c`, `min_c`, `set_line`, "
                      "`waited_c`, `wait_line`.",
    "collision": "the fields of `collision.Hit`: `body_a`, `body_b`, `t_s`, `row`, `gcode_line`, `layer`, `move_r`.",
    "state": "`state`, `command`; `allowed` (the states the command is accepted in), `reason` `moving`, or "
             "`plate` and `plate_job_id` (see below).",
    "not_found": "what was looked for (`job_id`, `artifact_id`, `backend`, ...); an unknown command: `service`, "
                 "`command`, `commands`.",
    "slicer": "`backend`: the external slicer that failed (its words are in the message).",
    "unavailable": "`key`, `timeout_s`, `reason` (`no_cell` with `cells`, `service_down` with `alive`, "
                   "`no_reply`, `no_queryable`), or `missing` (services not alive).",
    "forbidden": "`role`, `service`, `command`.",
    "store": "`file`, `reason` (`damaged`, `newer`, `migration`, `open`); `problem` when damaged; `table`, "
             "`version` when newer or migrating.",
    "disk_full": "`service`, `path`, `free_mb`, `need_mb` (in MiB).",
    "robot": "`robot` (the controller's address, `franka:HOST`), `reason` (`unreachable`, `busy`, `version`, "
             "`fault`, `lost`, `refused`); `server_version`, `library_version` for `version`.",
}
