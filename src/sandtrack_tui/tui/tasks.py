"""Background tasks (tracking, sync, calibration, training, export, comparison): Textual thread
workers that report through messages, never by touching widgets; a failure becomes a notification."""

from __future__ import annotations

import functools
import inspect
import time
from dataclasses import dataclass

from textual.message import Message
from textual.worker import Worker, WorkerState, get_current_worker

from ..errors import NotAvailableYet, SandtrackError
from ..store import Project


def guarded(fn):
    """Turn any exception of a UI handler into an error notification: never a dead app."""
    if inspect.iscoroutinefunction(fn):
        @functools.wraps(fn)
        async def async_wrapper(self, *args, **kwargs):
            try:
                return await fn(self, *args, **kwargs)
            except Exception as exc:  # noqa: BLE001
                self.report_error(exc)

        return async_wrapper

    @functools.wraps(fn)
    def wrapper(self, *args, **kwargs):
        try:
            return fn(self, *args, **kwargs)
        except Exception as exc:  # noqa: BLE001
            self.report_error(exc)

    return wrapper


@dataclass
class Task:
    name: str
    worker: Worker | None = None
    cancel_requested: bool = False


class TaskProgress(Message):
    def __init__(self, name: str, done: int, total: int, text: str = "") -> None:
        super().__init__()
        self.name, self.done, self.total, self.text = name, done, total, text


class TaskFinished(Message):
    def __init__(self, name: str, text: str, error: str | None = None, refresh_points: bool = True) -> None:
        super().__init__()
        self.name, self.text, self.error, self.refresh_points = name, text, error, refresh_points


class TasksMixin:
    """Part of SandtrackApp: one background task at a time, with a progress bar and cancel."""

    def _worker_project(self) -> Project:
        """Workers use their own connection: SQLite transactions must not interleave with the UI's."""
        return Project.open(self.project.path)

    def run_task(self, name: str, fn, on_result=None, refresh_points: bool = True) -> None:
        """Run fn(progress, should_stop) in a thread worker; progress(done, total) posts throttled
        messages; the result goes to on_result on the UI thread; errors become notifications."""
        if self.bg_task is not None:
            self.notify(f"{self.bg_task.name} is still running (escape cancels it)", severity="warning")
            return
        task = Task(name)
        self.bg_task = task
        bar = self._w['task-bar']
        bar.update(total=None, progress=0)
        self._w['task-label'].update(f"{name} (esc cancels)")
        self._w['task'].add_class("-running")
        self._task_results: dict = {}
        if hasattr(self.screen, "task_started"):
            self.screen.task_started(name)

        app = self

        def worker() -> None:
            last = [0.0]
            me = get_current_worker()

            def progress(done, total, text: str = "", *_, **__):
                now = time.perf_counter()
                if now - last[0] >= 0.2 or done >= total:
                    last[0] = now
                    app.post_message(TaskProgress(name, int(done), int(total), str(text)))

            def should_stop() -> bool:
                return task.cancel_requested or me.is_cancelled

            try:
                result = fn(progress, should_stop)
            except NotAvailableYet as exc:
                app.post_message(TaskFinished(name, "", str(exc), refresh_points))
                return
            except SandtrackError as exc:
                app.post_message(TaskFinished(name, "", str(exc), refresh_points))
                return
            except Exception as exc:  # noqa: BLE001 - any failure becomes a notification, never a dead app
                app.post_message(TaskFinished(name, "", f"{type(exc).__name__}: {exc}", refresh_points))
                return
            app._task_results[name] = (result, on_result)
            stopped = " (cancelled, kept what was done)" if task.cancel_requested else ""
            app.post_message(TaskFinished(name, f"{name} done{stopped}", None, refresh_points))

        task.worker = self.run_worker(worker, name=name, group="task", exclusive=True, thread=True,
                                      exit_on_error=False)

    @guarded
    def on_task_progress(self, msg: TaskProgress) -> None:
        bar = self._w['task-bar']
        bar.update(total=max(msg.total, 1), progress=msg.done)
        if hasattr(self.screen, "task_progress"):
            self.screen.task_progress(msg.done, msg.total, msg.text)
        if self.bg_task is not None and self.bg_task.name.startswith("tracking") and time.perf_counter() - getattr(
                self, "_last_live_reload", 0.0) > 1.0:
            self._last_live_reload = time.perf_counter()
            self.reload_points()
            self.update_overlays()

    @guarded
    def on_task_finished(self, msg: TaskFinished) -> None:
        self.bg_task = None
        self._w['task'].remove_class("-running")
        self._w['task-bar'].update(total=100, progress=0)
        for scr in self.screen_stack:
            if hasattr(scr, "task_finished"):
                scr.task_finished()
        if msg.refresh_points:
            self.reload_points()
            self.refresh_all()
        if msg.error:
            self.notify(f"{msg.name}: {msg.error}", severity="error", timeout=10)
            return
        result, on_result = self._task_results.pop(msg.name, (None, None))
        if on_result is not None:
            on_result(result)
        elif msg.text:
            self.notify(msg.text)

    def on_worker_state_changed(self, event: Worker.StateChanged) -> None:
        if event.state == WorkerState.ERROR and self.bg_task is not None and event.worker is self.bg_task.worker:
            self.post_message(TaskFinished(self.bg_task.name, "", str(event.worker.error)))

    def action_cancel(self) -> None:
        if self.bg_task is None:
            if self.range_in is not None or self.range_out is not None:
                self.range_in = self.range_out = None
                self.refresh_all()
            return
        self.bg_task.cancel_requested = True
        if self.bg_task.worker is not None:
            self.bg_task.worker.cancel()
        self.notify(f"cancelling {self.bg_task.name}…")
