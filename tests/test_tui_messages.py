"""The console's screens talk in messages (issue 37, point 7): no screen or widget imports the app module or calls
the console's own methods; data comes down as the console's reactives (watched), what the operator asks goes up as
a message of fabric.tui.messages that the console handles with ``@on``."""
from __future__ import annotations

import ast
import asyncio
import inspect
import time
from pathlib import Path

import pytest
from textual.app import App
from textual.reactive import Reactive

import fabric.tui
from fabric import schemas as s
from fabric.tui import messages
from fabric.tui.app import FabricConsole
from fabric.tui.messages import CallRequested, JobRemoved, Reply, ReprintRequested
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.jobs import JobsScreen

from support.tui_stub import StubClient

pytestmark = pytest.mark.timeout(60)

TUI = Path(fabric.tui.__file__).parent
VIEWS = sorted([*(TUI / "screens").glob("*.py"), *(TUI / "widgets").glob("*.py")])
APP_MODULE = "fabric.tui.app"


# --- static: what the screens and widgets may know of the console ------------------------------------------

def tree_of(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, and every ``module.name`` it imports from one (relative ones resolved)."""
    package = ".".join(path.relative_to(TUI.parent.parent).with_suffix("").parts[:-1])
    out: set[str] = set()
    for node in ast.walk(tree_of(path)):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package.split(".")[:len(package.split(".")) - node.level + 1]) if node.level else ""
            module = ".".join(part for part in (base, node.module or "") if part)
            out.add(module)
            out |= {f"{module}.{alias.name}" for alias in node.names}
    return out


def is_self_app(node: ast.AST, aliases: set[str]) -> bool:
    """``self.app``, or a name bound to it (``app = self.app``)."""
    if isinstance(node, ast.Name):
        return node.id in aliases
    return (isinstance(node, ast.Attribute) and node.attr == "app" and isinstance(node.value, ast.Name)
            and node.value.id == "self")


def app_uses(path: Path) -> tuple[list[str], list[str]]:
    """(the attributes read on the app, the app attributes watched) in ``path``."""
    tree = tree_of(path)
    aliases = {target.id for node in ast.walk(tree) if isinstance(node, ast.Assign) and is_self_app(node.value, set())
               for target in node.targets if isinstance(target, ast.Name)}
    read, watched = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and is_self_app(node.value, aliases):
            read.append(node.attr)
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "watch"
                and len(node.args) >= 2 and is_self_app(node.args[0], aliases)
                and isinstance(node.args[1], ast.Constant)):
            watched.append(node.args[1].value)
    return read, watched


def textual_api(name: str) -> bool:
    """A name of Textual's App the console does not define itself (its own methods, reactives and the
    attributes it sets in ``__init__`` are not the App's)."""
    return hasattr(App, name) and name not in vars(FabricConsole)


def test_no_screen_or_widget_imports_the_app_module():
    assert len(VIEWS) >= 10, VIEWS
    for path in VIEWS:
        modules = imported_modules(path)
        assert not {m for m in modules if m == APP_MODULE or m.startswith(APP_MODULE + ".")}, path.name
        assert "fabric.tui.FabricConsole" not in modules and "FabricConsole" not in path.read_text(), path.name


def test_screens_use_only_textuals_app_api_and_watch_only_the_consoles_reactives():
    """``self.app.push_screen`` and ``self.app.call_from_thread`` are Textual's; ``self.app.run_call``,
    ``self.app.jobs`` or ``self.app.client`` are the console's and may not be read (a message goes up instead, the
    data comes down watched)."""
    all_read, all_watched = set(), set()
    for path in VIEWS:
        read, watched = app_uses(path)
        for name in read:
            assert textual_api(name), f"{path.name}: self.app.{name}"
        for name in watched:
            assert isinstance(inspect.getattr_static(FabricConsole, name, None), Reactive), f"{path.name}: {name}"
            assert name in vars(FabricConsole), f"{path.name} watches {name}, not one of the console's reactives"
        all_read |= set(read)
        all_watched |= set(watched)
    assert {"push_screen", "call_from_thread"} <= all_read          # the scan sees what is there
    assert {"jobs", "station_state", "client", "reply", "log_entry"} <= all_watched
    for name in ("run_call", "show_reply", "reprint", "jobs", "client", "station_state", "log_lines", "on_mount"):
        assert not textual_api(name)                                 # what the check above refuses


def test_every_message_a_screen_posts_is_handled_by_the_console_with_on():
    handled = set()
    for node in ast.walk(tree_of(TUI / "app.py")):
        if isinstance(node, ast.FunctionDef):
            for deco in node.decorator_list:
                if isinstance(deco, ast.Call) and isinstance(deco.func, ast.Name) and deco.func.id == "on":
                    handled |= {arg.id for arg in deco.args if isinstance(arg, ast.Name)}
    posted = set()
    for path in VIEWS:
        for node in ast.walk(tree_of(path)):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "post_message" and node.args and isinstance(node.args[0], ast.Call)
                    and isinstance(node.args[0].func, ast.Name)):
                posted.add(node.args[0].func.id)
    assert {"CallRequested", "JobRemoved", "ReprintRequested", "Reply"} <= posted
    assert posted <= set(messages.__all__), posted - set(messages.__all__)
    assert set(messages.__all__) <= handled, set(messages.__all__) - handled


# --- Pilot: a screen's message reaches the console and is handled ----------------------------------------

def jobs() -> list[s.JobRecord]:
    return [s.JobRecord(job_id="a1b2c3d4e5f6", filename="bracket.stl", state="printing", model_id="m1"),
            s.JobRecord(job_id="b2c3d4e5f6a1", filename="vase.stl", state="queued", prepared=True),
            s.JobRecord(job_id="c3d4e5f6a1b2", filename="gear.gcode", source="gcode", state="finished",
                        model_id="m3", ended_s=1000.0, started_s=900.0)]


async def until(pilot, predicate, timeout_s: float = 10.0, what: str = "condition") -> None:
    end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < end, f"{what} not reached in {timeout_s:g} s"
        await pilot.pause(0.02)


def run(scenario, app: FabricConsole, seen: list | None = None) -> None:
    async def go() -> None:
        async with app.run_test(size=(80, 24), message_hook=seen.append if seen is not None else None) as pilot:
            await scenario(pilot, app)
    asyncio.run(go())


def test_a_job_removed_on_the_jobs_screen_reaches_the_console_as_a_message():
    """No client: the message alone takes the job off the console's list, and so off the screen."""
    async def scenario(pilot, app) -> None:
        app.jobs = jobs()
        await pilot.press("2")
        await until(pilot, lambda: isinstance(app.screen, JobsScreen))
        queue_t = app.screen.query_one("#queue")
        await until(pilot, lambda: queue_t.row_count == 2)
        app.screen.post_message(JobRemoved("b2c3d4e5f6a1"))          # as the screen's remove does, once removed
        await until(pilot, lambda: queue_t.row_count == 1, what="the row gone")
        assert [r.job_id for r in app.jobs] == ["a1b2c3d4e5f6", "c3d4e5f6a1b2"]
        assert app.screen.jobs == app.jobs                           # and down again to the screen
    run(scenario, FabricConsole(None))


def test_the_jobs_screens_commands_go_up_as_messages_and_are_answered():
    client = StubClient(jobs=jobs())
    client.artifacts["m3"] = b"G1 X1\n"
    seen: list = []

    def posted(kind: type) -> list:
        return [m for m in seen if isinstance(m, kind)]

    async def scenario(pilot, app) -> None:
        await until(pilot, lambda: app.cell != "", what="the link")
        await pilot.press("2")
        await until(pilot, lambda: isinstance(app.screen, JobsScreen) and app.screen.query_one("#queue").row_count)
        queue_t = app.screen.query_one("#queue")
        queue_t.focus()
        # a job that does not move: refused on the screen, said on the console's reply line and in its log
        await pilot.press("left_square_bracket")
        await until(pilot, lambda: app.reply is not None and app.reply[0] == "job move", what="the refusal")
        assert not app.reply[1] and "only a waiting job" in app.reply[2]
        assert any(m.command == "job move" for m in posted(Reply))
        assert any("job move: REFUSED only a waiting job" in line for line in app.log_lines)
        assert str(app.screen.query_one("#reply").render()).startswith(" job move ")
        # remove, confirmed: the call goes up, the supervisor is asked, the job leaves the console's list
        queue_t.move_cursor(row=1)
        await pilot.press("delete")
        await until(pilot, lambda: isinstance(app.screen, ConfirmDialog))
        await pilot.press("y")
        await until(pilot, lambda: app.reply is not None and app.reply[0] == "job remove", what="the answer")
        assert app.reply[1:] == (True, "removed job b2c3d4e5f6a1")
        assert {m.label for m in posted(CallRequested)} == {"job remove"}
        await until(pilot, lambda: posted(JobRemoved), what="the removal posted")
        assert {m.job_id for m in posted(JobRemoved)} == {"b2c3d4e5f6a1"}
        await until(pilot, lambda: "b2c3d4e5f6a1" not in [r.job_id for r in app.jobs], what="off the list")
        assert client.called("job_remove") == ["b2c3d4e5f6a1"]
        # print again from the history: the console fetches the file and submits it
        app.screen.query_one("#history").focus()
        await pilot.press("R")
        await until(pilot, lambda: client.called("submit"), what="the reprint")
        assert [m.record.job_id for m in posted(ReprintRequested)][:1] == ["c3d4e5f6a1b2"]
        await until(pilot, lambda: app.reply is not None and app.reply[0] == "print again")
        assert app.reply[1] and "gear.gcode again" in app.reply[2]
    run(scenario, FabricConsole(client), seen)
