"""The training job: ``nerf_core check`` on the dataset, then ``nerf_core train``, in a child process."""
from __future__ import annotations

from typing import List

from ..bridge import child_process
from ..common.jobs import ProcessJob


class TrainJob(ProcessJob):
    """``nerf_core check`` on the dataset, then ``nerf_core train``, both in the background."""

    kind = "training"

    def __init__(self, scene_name: str, python: str, dataset: str, run: str, command: List[str],
                 check: bool = True):
        super().__init__(scene_name)
        self.python, self.dataset, self.run, self.command = python, dataset, run, command
        if check:
            self.stage = "check"
            # What train refuses stops the job; a dataset of another tool (the original NeRF scenes,
            # instant-ngp, nerfstudio) lacks fields our exports add, and still trains.
            self.process = child_process.BackgroundProcess(
                [python, "-m", "nerf_core", "check", dataset, "--for-training"]).start()
        else:
            self.stage = "train"
            self.process = child_process.BackgroundProcess(command).start()

    def child_exited(self) -> str:
        if self.stage != "check":
            return super().child_exited()
        if self.process.returncode != 0:
            lines = [ln for ln in self.process.tail if ln.strip()]
            detail = "\n".join(lines[-5:]) or f"exit code {self.process.returncode}"
            return self.fail(f"Dataset {self.dataset} is not usable:\n{detail}")
        self.stage = "train"
        self.process = child_process.BackgroundProcess(self.command).start()
        return self.state

    def succeeded(self) -> str:
        self.state = "done"
        self.message = f"Training finished: {self.run}"
        return self.state
