"""The page of ``curved_print_bench.py``: its rows as docs/bench/curved_print.md."""
from __future__ import annotations

import numpy as np

CELL = "irb140-multiaxis"

def _f(v: object, fmt: str = "{:.3f}") -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)


def _by_joint(plan: dict) -> str:
    joints = plan.get("unreachable_by_joint") or {}
    return ", ".join(f"{k} {v}" for k, v in joints.items()) or "-"


def _unreachable(plan: dict) -> str:
    counts = {k: v for k, v in (plan.get("unreachable_by_reason") or {}).items() if k != "singular"}
    return ", ".join(f"{v} {k}" for k, v in counts.items()) or "none"


def _verdict(c: dict) -> str:
    free = c.get("collision_free")
    if free is True:
        return f"collision-free, {_f(c.get('clearance_mm'))} mm ({c.get('clearance_body') or '-'})"
    if free is False:
        return f"COLLISION: {c.get('first_hit')}"
    return str(c.get("error") or "-")


def report(rows: list[dict], meta: dict[str, object]) -> str:
    lines = [
        "# Curved layers from STL to a checked print (issues 21 and 38)",
        "",
        f"`.venv/bin/python tools/bench/curved_print_bench.py` on {meta['machine']} ({meta['cpus']} CPUs, "
        f"{meta['load']}). Cell `{CELL}` (fabric/cells/{CELL}.toml) as the five service processes; every "
        "figure comes from a whole `fabric-cli` process against them: `slice --layers planar|curved`, `plan` "
        "(reachability of every target), `check` (plan, then the certified collision check of every motion "
        "against the part as printed) and `job submit --layers curved --start --rtf 0` printed on the twin to "
        "its end. The shapes: the four of the first tests (dome, frustum with 55 deg walls, arch, wing), three "
        "nobody tuned for (a hook curling away from the robot, a vase with a lip flaring 50 deg, a bridge whose "
        "span is skewed 30 deg and turned 35 deg on the plate: `OTHER_SHAPES`) and the bundled samples.",
        "",
        "Before issue 38 (commit 8e8827e, measured the same way in the session that changed it): the hook "
        "sliced curved planned not runnable, 2676 targets at A5's limit with the reason's detail empty; the flared "
        "vase sliced curved in 165 s and the twisted vase in 387 s (below: every target reachable, and "
        "7.3 s and 12.4 s).",
        "",
        "Overhang: faces with n . d < -sin 45 (d = +z planar, the field's build direction curved), faces on the "
        "plate excluded. Cusp: the top surface's staircase error (mean / max). Tilt: of the nozzle axis from +z.",
        "",
        "| shape | layers planar / curved | overhang mm2 planar / curved | thickness mm (ratio) | max tilt deg "
        "| neighbour deg | cusp mean mm planar / curved | cusp max mm planar / curved | slice s planar / curved |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p, c = r["planar"], r["curved"]
        g = c["figures"] or {}
        lines.append(
            f"| {r['shape']} | {p['layers']} / {c['layers']} | {_f(g.get('planar_overhang_mm2'), '{:.0f}')} / "
            f"{_f(g.get('overhang_mm2'), '{:.1f}')} | {_f(g.get('thickness_min_mm'))}-{_f(g.get('thickness_max_mm'))}"
            f" ({_f(g.get('thickness_ratio_r'), '{:.2f}')}) | {_f(g.get('max_tilt_deg'), '{:.1f}')} "
            f"| {_f(g.get('max_neighbour_deg'), '{:.1f}')} | {_f(g.get('planar_cusp_mean_mm'))} / "
            f"{_f(g.get('cusp_mean_mm'))} | {_f(g.get('planar_cusp_max_mm'))} / {_f(g.get('cusp_max_mm'))} "
            f"| {_f(p['slice_s'], '{:.1f}')} / {_f(c['slice_s'], '{:.1f}')} |")
    lines += ["", "Reachability (`fabric-cli plan`), collisions (`fabric-cli check`: the certified clearance and the "
              "body pair it was measured on, the sweep's time) and the print (`job submit --layers curved`):",
              "",
              "| shape | layers | targets | reachable | unreachable (by joint) | plan s | collision-free, clearance mm "
              "(body) | segments | certify s | check s | print | deposited / planned mm3 | beads | max bead tilt deg |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        pr = r["print"]
        for layers in ("planar", "curved"):
            c = r[layers]
            plan = c.get("plan") or {}
            reach = "-" if plan.get("feasible_r") is None else f"{100 * plan['feasible_r']:.2f} %"
            printed = (f"{pr['state']} | {_f(pr.get('deposited_mm3'), '{:.0f}')} / "
                       f"{_f(pr.get('planned_mm3'), '{:.0f}')} | {pr.get('beads', '-')} | "
                       f"{_f(pr.get('max_bead_tilt_deg'), '{:.1f}')}") if layers == "curved" else "- | - | - | -"
            unreachable = f"{_unreachable(plan)} ({_by_joint(plan)})"
            lines.append(f"| {r['shape']} | {layers} | {plan.get('targets') or '-'} | {reach} | {unreachable} "
                         f"| {_f(plan.get('elapsed_s'), '{:.1f}')} | {_verdict(c)} | {c.get('segments') or '-'} "
                         f"| {_f(c.get('certify_s'), '{:.1f}')} | {_f(c['check_s'], '{:.1f}')} | {printed} |")
    return "\n".join(lines) + "\n"

