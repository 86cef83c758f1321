"""The background job behind "Set up PyTorch": runs ``torch_setup``'s plan one command at a time.

Each command (create the venv, update pip, install, verify) is a ``child_process.BackgroundProcess``
advanced by the one job follower (``jobs``), so Blender stays responsive through a download of
gigabytes; Cancel stops pip like it stops a trainer. The last command is the trainer's own probe, whose
result is cached (``child_process.remember_probe``): training right after the setup does not wait for
another torch import.
"""
from __future__ import annotations

import os

import bpy

from ..bridge import child_process, torch_setup
from ..bridge.child_process import SetupError
from ..bridge.progress import ProgressParser
from .jobs import ProcessJob

KEY = "torch_setup"  # the job registry's key (one setup at a time)


def private_env_dir(package: str, create: bool = False) -> str:
    """Where the private environment lives: the extension's user folder (kept across upgrades of the
    extension). The add-on loaded some other way (from a checkout by tests or scripts) is no extension:
    then Blender's user configuration folder, under ``nerf_bridge/``."""
    try:
        return bpy.utils.extension_path_user(package, path=torch_setup.ENV_DIRNAME, create=create)
    except ValueError:  # "package" does not name an extension
        base = bpy.utils.user_resource("CONFIG", path="nerf_bridge", create=create)
        return os.path.join(base, torch_setup.ENV_DIRNAME)


class TorchSetupJob(ProcessJob):
    """Build the environment ``plan`` describes; ``message`` says what was installed, or why not."""

    kind = "PyTorch setup"
    interval = 0.25

    def __init__(self, plan: torch_setup.SetupPlan):
        super().__init__(scene_name="")  # preferences, not a scene
        self.plan = plan
        self.index = -1
        self.probe = None  # child_process.ProbeResult once verified
        try:  # a setup that does not finish must not leave an environment that claims to be ready
            os.remove(os.path.join(plan.env_dir, torch_setup.READY_FILE))
        except FileNotFoundError:
            pass
        self._start_next()

    @property
    def step(self) -> torch_setup.Step:
        return self.plan.steps[self.index]

    def _start_next(self) -> None:
        self.index += 1
        step = self.step
        parser = torch_setup.PipProgress if step.name in ("pip", "install") else ProgressParser
        self.process = child_process.BackgroundProcess(step.cmd, env=step.env, parser_class=parser).start()

    def fraction(self) -> float:
        """How far the whole setup is, in [0, 1]."""
        step = self.step
        share = self.process.progress.share() if isinstance(self.process.progress, torch_setup.PipProgress) else 0.0
        return 1.0 if self.state == "done" else step.start + (step.end - step.start) * share

    def status(self) -> str:
        """What the setup is doing now, for the preferences panel."""
        progress = self.process.progress
        if self.step.name == "install" and isinstance(progress, torch_setup.PipProgress) and progress.phase:
            return progress.status()
        return self.step.label

    def status_bar_text(self):
        return f"Setting up PyTorch: {self.status()} ({100 * self.fraction():.0f}%)"

    def child_exited(self) -> str:
        code = self.process.returncode
        lines = list(self.process.tail)
        if self.step.name == "verify":
            self.probe = child_process.remember_probe(self.plan.python, code, lines)
        if code != 0:
            tail = "\n".join(lines[-12:])
            return self.fail(f"PyTorch setup stopped: {torch_setup.explain_failure(self.step, lines, self.plan)}"
                             + (f"\n--- last lines of the log ---\n{tail}" if tail else ""))
        return self.succeeded()

    def succeeded(self) -> str:
        if self.index + 1 < len(self.plan.steps):
            self._start_next()
            return self.state
        torch_setup.mark_ready(self.plan.env_dir, self.plan.device, self.probe.message)
        self.state = "done"
        self.message = f"PyTorch is set up ({self.probe.message}): training runs in {self.plan.python}"
        return self.state

    def _cancelled(self) -> str:
        self.state = "cancelled"
        self.message = (f"PyTorch setup cancelled while {self.step.label.lower()}: the environment is incomplete; "
                        "press Set up PyTorch to start again")
        return self.state


def start(plan: torch_setup.SetupPlan, running_jobs) -> TorchSetupJob:
    """A new setup job for ``plan``; SetupError when a running job uses the environment it would replace."""
    for job in running_jobs:
        proc = getattr(job, "process", None)
        if proc is not None and proc.cmd and os.path.abspath(proc.cmd[0]) == os.path.abspath(plan.python):
            raise SetupError(f"A {job.kind} job runs in {plan.python}: cancel it or let it finish before "
                             "setting up PyTorch again.")
    return TorchSetupJob(plan)
