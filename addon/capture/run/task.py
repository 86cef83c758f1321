"""A prepared ``CaptureJob`` followed by the job follower, one frame per timer event."""
from __future__ import annotations

from typing import Callable, Optional

from ...common.jobs import Job
from .job import CaptureJob


class CaptureTask(Job):
    """A ``CaptureJob`` (already prepared), one frame per update; Blender renders in this
    process, so each update blocks for one frame and the UI answers between frames."""

    kind = "capture"
    interval = 0.0  # a frame per timer event: the render itself is the wait
    esc_cancels = True
    keeps_timer_event = True
    cancel_report = "WARNING"

    def __init__(self, scene_name: str, job: CaptureJob,
                 cancel_requested: Callable[[], bool] = lambda: False, progress_text: Callable[[], str] = str):
        super().__init__(scene_name)
        self.capture = job
        self.cancel_requested = cancel_requested  # the Cancel button's flag, read before each frame
        self.progress_text = progress_text

    def update(self) -> str:
        if self.state != "running":
            return self.state
        if self.cancel_requested():
            self.cancel()
            return self.state
        try:
            more = self.capture.step()
        except Exception as exc:  # a failed frame must not leave the job running: keep what is rendered
            self.cancel()
            return self.fail(f"capture stopped: {exc}; {self.message}")
        if not more:
            summary = self.capture.finish()
            self.state = "done"
            self.message = f"done: {summary['frames']} frames in {summary['out']}"
        return self.state

    def cancel(self, wait: bool = True) -> None:
        """Stop after the current frame: the folder stays consistent and the next capture resumes it."""
        if self.state != "running":
            return
        summary = self.capture.cancel()
        self.state = "cancelled"
        self.message = (f"cancelled: {summary['rendered'] + summary['kept']}/{summary['frames']} frames kept; "
                        "capture again to resume")

    def status_bar_text(self) -> Optional[str]:
        return f"NeRF capture {self.progress_text()} - Esc to cancel"
