"""A Franka Research 3 through franky-control: the libfranka network protocol (FCI), on a real arm or on
franky-sim.

The arm follows the station's reference under a joint impedance controller that runs in libfranka's 1 kHz
loop (franky's ``JointImpedanceTrackingMotion``); a streaming thread of this driver sets its target every
``STREAM_PERIOD_S`` to the reference's joints and rate at that instant and records the measured joints. Why
this motion type (measured on franky-sim 1.0.4, a 100 mm line at 20 mm/s, docs/robots.md): Franka's own
motion generators settle short under gravity (0.019 rad) and Cartesian waypoints run faster than timed; the
tracking controller with the gains below followed the line within 0.1 mm (p50), with its default gains 14.6 mm.

libfranka stops the arm itself when its control loop stops hearing from us (the station killed: the
connection's UDP stream ends), and the reference holds its last sample when the station stops filling it.
"""
from __future__ import annotations

import socket
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from fabric.drivers.controller import ControllerInfo, ControllerStatus, Tracking
from fabric.drivers.reference import Reference
from fabric.wire.errors import RobotError

__all__ = ["FrankaController", "FCI_PORT", "CONNECT_TIMEOUT_S", "STREAM_PERIOD_S", "STIFFNESS_NM_RAD",
           "SERVER_VERSION"]

FCI_PORT = 1337                 # libfranka's command port
CONNECT_TIMEOUT_S = 5.0         # libfranka's own is 60 s; a second client waits for ever
STREAM_PERIOD_S = 0.002         # the streaming thread's step (libfranka's loop runs at 1 kHz on its own)
POLL_EVERY = 10                 # the motion's errors are polled every this many steps (20 ms)
SILENT_S = 0.3                  # the robot's clock not moving on for this long while driven: the link is lost
                                # (libfranka itself says so only after its own timeout, about 2 s)
STIFFNESS_NM_RAD = (3000.0, 3000.0, 3000.0, 2500.0, 2500.0, 2000.0, 2000.0)
"""Franka's own default joint impedance (libfranka's setJointImpedance): known to be safe on the arm."""
MAX_DELTA_TAU_NM = 1.0
"""The torque step per 1 ms cycle the controller may command: FR3's torque rate limit (1000 Nm/s)."""
LEAD_S = 0.015
"""The reference is sent this far ahead of now: the controller's lag behind it (measured on franky-sim: the
measured TCP trailed the commanded one by 15-25 ms at 20 mm/s), so the arm is where the twin says, when."""
DOF = 7
SERVER_VERSION = 10
"""The robot server version franky-control 2.0 speaks (libfranka refuses any other on connecting)."""
KEEP_TRACKING = 20000           # steps kept for a reader that falls behind (40 s)


def _franky() -> Any:
    try:
        import franky
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError("franky is not installed", name="franky") from exc
    return franky


class FrankaController:
    """A Franka arm at ``host``: the :class:`~fabric.drivers.controller.Controller` protocol."""

    kind = "franka"

    def __init__(self, host: str, *, connect_timeout_s: float = CONNECT_TIMEOUT_S,
                 stiffness_nm_rad: tuple[float, ...] = STIFFNESS_NM_RAD, period_s: float = STREAM_PERIOD_S,
                 port: int = FCI_PORT, lead_s: float = LEAD_S,
                 damping_nms_rad: tuple[float, ...] | None = None) -> None:
        self.host, self.port = host, port
        self.address = f"franka:{host}"
        self.connect_timeout_s = connect_timeout_s
        self.stiffness_nm_rad = tuple(stiffness_nm_rad)
        self.period_s = period_s
        self.lead_s = lead_s
        self.damping_nms_rad = damping_nms_rad
        self._robot: Any = None
        self._motion: Any = None
        self._thread: threading.Thread | None = None
        self._halt = threading.Event()
        self._steps: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=KEEP_TRACKING)
        self._fault = ""
        self._lost = False
        self._lock = threading.RLock()       # connecting, following, stopping: one at a time
        self._last = ControllerStatus(self.address, connected=False)

    # --- connecting -------------------------------------------------------------------------

    def _error(self, reason: str, message: str, **details: Any) -> RobotError:
        return RobotError(f"robot {self.address}: {message}", robot=self.address, reason=reason, **details)

    def _probe(self) -> None:
        """Is anything listening at the command port? One typed line for a wrong or dead host."""
        try:
            with socket.create_connection((self.host, self.port), timeout=min(2.0, self.connect_timeout_s)):
                pass
        except ConnectionRefusedError:
            raise self._error("unreachable", f"nothing listens on {self.host}:{self.port} (the host answers: "
                              "is FCI activated in Desk, or franky-sim running?)") from None
        except OSError as exc:
            why = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
            raise self._error("unreachable", f"cannot reach {self.host}:{self.port} ({why}): check the address "
                              "and the network to the controller") from None

    def connect(self) -> ControllerInfo:
        with self._lock:
            return self._connect()

    def _connect(self) -> ControllerInfo:
        franky = _franky()
        self._probe()
        box: dict[str, Any] = {}

        def open_robot() -> None:
            try:
                box["robot"] = franky.Robot(self.host, realtime_config=franky.RealtimeConfig.Ignore)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                box["error"] = exc

        opener = threading.Thread(target=open_robot, name=f"{self.address}:connect", daemon=True)
        opener.start()
        opener.join(self.connect_timeout_s)
        if opener.is_alive():      # the port answers, the handshake does not: another client holds it
            raise self._error("busy", f"{self.host} answers but did not let us in within "
                              f"{self.connect_timeout_s:g} s: another client holds the robot (a second station, "
                              "Desk's own control, or a program of someone else): stop it, then connect again")
        exc = box.get("error")
        if exc is not None:
            raise self._connect_error(franky, exc) from None
        self._robot = box["robot"]
        self._fault, self._lost = "", False
        q = np.asarray(self._robot.current_joint_positions, dtype=float)
        return ControllerInfo(self.address, self.kind, SERVER_VERSION, DOF, q)

    def _connect_error(self, franky: Any, exc: BaseException) -> RobotError:
        if isinstance(exc, franky.IncompatibleVersionException):
            got = _version_in(str(exc))
            return self._error("version", f"the robot's server version {got if got is not None else '?'} is not "
                               f"the one franky-control speaks ({SERVER_VERSION}): update the robot's system "
                               "image or install the franky-control release for it",
                               server_version=got, library_version=SERVER_VERSION)
        if isinstance(exc, franky.NetworkException):
            return self._error("unreachable", f"the connection failed: {exc}")
        return self._error("refused", f"connecting failed: {type(exc).__name__}: {exc}")

    # --- following ----------------------------------------------------------------------------

    def follow(self, reference: Reference) -> None:
        with self._lock:
            self._follow(reference)

    def _follow(self, reference: Reference) -> None:
        franky = _franky()
        if self._robot is None:
            raise self._error("lost", "not connected: recover first")
        self._stop()
        q0 = np.asarray(self._robot.current_joint_positions, dtype=float)
        if reference.last() is None:
            reference.hold(q0, time.monotonic())
        damping = None if self.damping_nms_rad is None else np.array(self.damping_nms_rad)
        motion = franky.JointImpedanceTrackingMotion(stiffness=np.array(self.stiffness_nm_rad), damping=damping,
                                                     max_delta_tau=MAX_DELTA_TAU_NM)
        motion.set_reference(franky.JointReference(q0, np.zeros(DOF)))
        try:
            self._robot.move(motion, asynchronous=True)
        except Exception as exc:  # noqa: BLE001 - libfranka's command errors, one typed line
            raise self._error("refused", f"the robot did not take the motion: {exc}") from None
        self._motion, self._fault = motion, ""
        self._halt.clear()
        self._thread = threading.Thread(target=self._stream, args=(reference, motion), daemon=True,
                                        name=f"{self.address}:stream")
        self._thread.start()

    def _stream(self, reference: Reference, motion: Any) -> None:
        franky = _franky()
        robot, n = self._robot, 0
        next_s = time.monotonic()
        heard_s, robot_ms = next_s, -1
        try:
            while not self._halt.is_set():
                now = time.monotonic()
                q_lead, dq, _dry = reference.at(now + self.lead_s)
                motion.set_reference(franky.JointReference(q_lead, dq))
                q_now = reference.at(now)[0]            # where the twin says the arm is now
                self._steps.append((now, q_now, np.asarray(robot.current_joint_positions, dtype=float)))
                n += 1
                if n % POLL_EVERY == 0:
                    robot.poll_motion()           # raises what ended the motion (its answer is no guide: franky 2.0
                    if not robot.is_in_control:   # says False while a motion runs)
                        self._fault = self._fault or "the robot's motion ended by itself"
                        return
                    ms = robot.state.time.to_msec()
                    if ms != robot_ms:
                        heard_s, robot_ms = now, ms
                    elif now - heard_s > SILENT_S:
                        self._lost = True
                        self._fault = f"the robot stopped answering (its clock stood still for {now - heard_s:.1f} s)"
                        return
                next_s += self.period_s
                pause_s = next_s - time.monotonic()
                if pause_s > 0:
                    self._halt.wait(pause_s)
                else:
                    next_s = time.monotonic()      # fell behind (a loaded host): go on from now
        except franky.NetworkException as exc:
            self._lost, self._fault = True, f"the connection to the robot was lost: {exc}"
        except franky.ControlException as exc:
            self._fault = f"the robot stopped in error: {_one_line(exc)}"
        except Exception as exc:  # noqa: BLE001 - any other end of the stream is a fault the station reports
            self._fault = f"streaming failed: {type(exc).__name__}: {_one_line(exc)}"

    def tracking(self) -> Tracking:
        steps = []
        while self._steps:
            steps.append(self._steps.popleft())
        if not steps:
            return Tracking.empty(DOF)
        t, qc, qm = zip(*steps, strict=True)
        return Tracking(np.array(t), np.array(qc), np.array(qm))

    def stop(self) -> None:
        with self._lock:
            self._stop()

    def _stop(self) -> None:
        thread, self._thread = self._thread, None
        self._halt.set()
        if thread is not None:
            thread.join(1.0)
        if self._motion is not None and self._robot is not None and not self._lost:
            self._motion = None
            try:
                self._robot.stop()
                self._robot.join_motion(timeout=1.0)
            except Exception:  # noqa: BLE001 - a motion that ended in error is already stopped; status says why
                pass
        self._motion = None

    # --- state -------------------------------------------------------------------------------

    def status(self) -> ControllerStatus:
        """The controller now; while another thread connects or stops it, the last status read (never waits)."""
        if not self._lock.acquire(blocking=False):
            return self._last
        try:
            self._last = self._status()
            return self._last
        finally:
            self._lock.release()

    def _status(self) -> ControllerStatus:
        st = ControllerStatus(self.address, connected=self._robot is not None and not self._lost,
                              following=self._thread is not None and self._thread.is_alive(),
                              fault=self._fault, lost=self._lost)
        if not st.connected:
            return st
        try:
            rs = self._robot.state
            st.mode = str(rs.robot_mode).rsplit(".", 1)[-1]
            st.errors = _active(rs.current_errors)
            st.robot_time_s = float(rs.time.to_sec()) if hasattr(rs.time, "to_sec") else None
            st.q_rad = np.asarray(rs.q, dtype=float)
            st.server_version = SERVER_VERSION
        except Exception as exc:  # noqa: BLE001 - a robot that stopped answering is lost
            self._lost, st.lost, st.connected = True, True, False
            self._fault = self._fault or f"the robot stopped answering: {_one_line(exc)}"
            st.fault = self._fault
        return st

    def recover(self) -> ControllerInfo:
        with self._lock:
            return self._recover()

    def _recover(self) -> ControllerInfo:
        self._stop()
        if self._lost or self._robot is None:
            self._robot = None
            return self._connect()
        try:
            if self._robot.has_errors and not self._robot.recover_from_errors():
                raise self._error("fault", "the robot's automatic error recovery did not clear its errors "
                                  f"({', '.join(self._status().errors) or 'none named'}): clear them in Desk")
        except RobotError:
            raise
        except Exception as exc:  # noqa: BLE001 - libfranka refused the recovery
            raise self._error("fault", f"error recovery failed: {_one_line(exc)}") from None
        self._fault = ""
        q = np.asarray(self._robot.current_joint_positions, dtype=float)
        return ControllerInfo(self.address, self.kind, SERVER_VERSION, DOF, q)

    def close(self) -> None:
        with self._lock:
            self._stop()
            self._robot = None


def _active(errors: Any) -> list[str]:
    """The names of the errors set in a franky ``Errors``."""
    names = [n for n in dir(errors) if not n.startswith("_") and isinstance(getattr(errors, n, None), bool)]
    return [n for n in names if getattr(errors, n)]


def _version_in(text: str) -> int | None:
    """The server's version in libfranka's incompatible-version message, if it names it."""
    import re
    m = re.search(r"server version:?\s*(\d+)", text, re.IGNORECASE) or re.search(r"(\d+)", text)
    return int(m.group(1)) if m else None


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())
