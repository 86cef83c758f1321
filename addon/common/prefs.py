"""Add-on preferences: which Python interpreter runs nerf_core (the one that has torch), and the ways
to get one: **Set up PyTorch** (a private environment the add-on builds, ``torch_setup_job``), an
interpreter found on the machine (**Find**), or any path the user types.

torch is never imported inside Blender; training and rendering run in this interpreter as a child
process. Empty means "Blender's own Python", used only when it can import torch.
"""
from __future__ import annotations

import os
import sys

import bpy
from bpy.props import BoolProperty, CollectionProperty, EnumProperty, StringProperty

from ..bridge import child_process, torch_setup
from ..bridge.child_process import SetupError
from . import jobs, torch_setup_job
from .ui_common import draw_error, draw_wrapped, report_and_cancel

# The add-on's own package (its preferences key): this module lives one level below it, in common/.
ADDON_PACKAGE = (__package__ or "").rpartition(".")[0]
DEVICE_ITEMS = [(b.key, b.label, f"{b.label}: {b.download} to download, {b.disk} on disk")
                for b in torch_setup.BUILDS.values()]


def get_preferences(context=None):
    """The add-on's preferences, or None when the add-on is not registered as an extension/add-on
    (e.g. imported by a script); callers then use the defaults."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_PACKAGE) if ADDON_PACKAGE else None
    return addon.preferences if addon is not None else None


def python_preference(context=None) -> str:
    prefs = get_preferences(context)
    return prefs.python_path if prefs is not None else ""


def online_access() -> bool:
    # Blender 4.2+: "Allow Online Access" (off in background mode unless --online-mode is given).
    return bool(getattr(bpy.app, "online_access", True))


def blender_python() -> str:
    """Blender's own Python binary; SetupError when it cannot be found."""
    return torch_setup.base_python(sys.executable, getattr(bpy.app, "binary_path_python", "") or "")


class NERF_OT_check_python(bpy.types.Operator):
    """Check that the chosen interpreter can import torch and nerf_core"""

    bl_idname = "nerf.check_python"
    bl_label = "Check Python"
    bl_options = {"INTERNAL"}

    def execute(self, context):
        try:
            python = child_process.resolve_interpreter(python_preference(context))
        except child_process.SetupError as exc:
            return report_and_cancel(self, exc)
        result = child_process.probe_interpreter(python)
        self.report({"INFO"}, f"{python}: {result.message}")
        return {"FINISHED"}


def _set_python_path(job: torch_setup_job.TorchSetupJob) -> None:
    # The user asked for this environment: training uses it from now on (the report says so).
    prefs = get_preferences()
    if job.state == "done" and prefs is not None:
        prefs.python_path = job.plan.python


class NERF_OT_setup_torch(bpy.types.Operator):
    """Create a private Python environment with PyTorch for training (downloads it, or installs it from a
    folder of wheels), in the background"""

    bl_idname = "nerf.setup_torch"
    bl_label = "Set up PyTorch"
    bl_options = {"INTERNAL"}

    device: EnumProperty(name="PyTorch build", items=DEVICE_ITEMS, default="CPU")
    wheel_dir: StringProperty(name="Wheel folder", default="", subtype="DIR_PATH",
                              description="Install only from this folder of .whl files (offline); empty: download")
    openexr: BoolProperty(name="OpenEXR", default=True, description="Also install OpenEXR (EXR datasets)")
    env_dir: StringProperty(name="Environment folder", default="", options={"HIDDEN", "SKIP_SAVE"},
                            description="Where to build it; empty: the extension's user folder")

    def plan(self, create: bool = False) -> torch_setup.SetupPlan:
        env_dir = self.env_dir or torch_setup_job.private_env_dir(ADDON_PACKAGE, create=create)
        return torch_setup.plan_setup(env_dir, blender_python(), self.device, bpy.path.abspath(self.wheel_dir),
                                      self.openexr, online=online_access())

    def invoke(self, context, event):
        try:
            self.plan()  # refuse before asking: offline without a folder, a missing folder, CUDA on macOS
        except SetupError as exc:
            return report_and_cancel(self, exc)
        try:
            return context.window_manager.invoke_props_dialog(self, width=520, title="Set up PyTorch",
                                                              confirm_text="Install")
        except TypeError:  # Blender before 4.1 has no title/confirm_text
            return context.window_manager.invoke_props_dialog(self, width=520)

    def draw(self, context):
        try:  # what will be fetched from where, and how big, before the user confirms
            text = self.plan().describe()
        except SetupError as exc:
            text = str(exc)
        draw_wrapped(self.layout, text, icon="INFO", width=80)
        self.layout.label(text="Blender stays usable meanwhile; the progress shows in the preferences.")

    def execute(self, context):
        try:
            if jobs.is_running(torch_setup_job.KEY):
                raise SetupError("PyTorch is already being set up: wait for it or cancel it.")
            job = torch_setup_job.start(self.plan(create=True), jobs.running())
        except SetupError as exc:
            return report_and_cancel(self, exc)
        job.on_end = _set_python_path
        jobs.add(torch_setup_job.KEY, job)
        jobs.follow(context)
        self.report({"INFO"}, f"Setting up PyTorch in {job.plan.env_dir}")
        return {"FINISHED"}


class NERF_OT_setup_torch_cancel(bpy.types.Operator):
    """Stop setting up PyTorch (the environment is left incomplete)"""

    bl_idname = "nerf.setup_torch_cancel"
    bl_label = "Cancel"
    bl_options = {"INTERNAL"}

    def execute(self, context):
        jobs.cancel_jobs(wait=False, keys=(torch_setup_job.KEY,))
        return {"FINISHED"}


class NerfFoundPython(bpy.types.PropertyGroup):
    label: StringProperty()
    python: StringProperty()
    ok: BoolProperty()
    message: StringProperty()


class NERF_OT_find_pythons(bpy.types.Operator):
    """Look for interpreters that can train: the private environment, this checkout's .venv, an active
    virtualenv or conda environment; each is checked (it imports torch, a few seconds each)"""

    bl_idname = "nerf.find_pythons"
    bl_label = "Find"
    bl_options = {"INTERNAL"}

    def execute(self, context):
        prefs = get_preferences(context)
        if prefs is None:
            return report_and_cancel(self, "The add-on's preferences are not available (it is not enabled).")
        prefs.found.clear()
        private = torch_setup_job.private_env_dir(ADDON_PACKAGE)
        for cand in torch_setup.candidate_interpreters(private_env=private):
            result = child_process.probe_interpreter(cand.python)
            item = prefs.found.add()
            item.label, item.python, item.ok, item.message = cand.label, cand.python, result.ok, result.message
        usable = sum(item.ok for item in prefs.found)
        self.report({"INFO"}, f"Found {len(prefs.found)} interpreter(s), {usable} with torch")
        return {"FINISHED"}


class NERF_OT_use_python(bpy.types.Operator):
    """Train with this interpreter"""

    bl_idname = "nerf.use_python"
    bl_label = "Use"
    bl_options = {"INTERNAL"}

    python: StringProperty()

    def execute(self, context):
        prefs = get_preferences(context)
        if prefs is None:
            return report_and_cancel(self, "The add-on's preferences are not available (it is not enabled).")
        prefs.python_path = self.python
        return {"FINISHED"}


def draw_setup(layout, prefs) -> None:
    """The Set up PyTorch box: build and source, then the button, or the running job's progress."""
    box = layout.box()
    box.label(text="Set up PyTorch", icon="CONSOLE")
    private = torch_setup_job.private_env_dir(ADDON_PACKAGE)
    job = jobs.get(torch_setup_job.KEY)
    if job is not None and job.state == "running":
        box.progress(factor=job.fraction(), type="BAR", text=job.status())
        box.operator(NERF_OT_setup_torch_cancel.bl_idname, icon="CANCEL")
        return
    col = box.column()
    col.prop(prefs, "torch_device", expand=True)
    build = torch_setup.BUILDS[prefs.torch_device]
    col.prop(prefs, "wheel_dir")
    col.prop(prefs, "torch_openexr")
    if prefs.wheel_dir:
        col.label(text="Installs only from this folder: no download, works offline.", icon="FILE_FOLDER")
    elif not online_access():
        col.label(text="Online access is off (Preferences > System > Network): choose a wheel folder.",
                  icon="ERROR")
    else:
        col.label(text=f"Downloads {build.download} ({build.disk} on disk) from download.pytorch.org and pypi.org.",
                  icon="URL")
    ready = torch_setup.is_ready(private)
    op = col.operator(NERF_OT_setup_torch.bl_idname, text="Reinstall PyTorch" if ready else "Set up PyTorch",
                      icon="IMPORT")
    op.device, op.wheel_dir, op.openexr = prefs.torch_device, prefs.wheel_dir, prefs.torch_openexr
    info = torch_setup.ready_info(private)
    col.label(text=f"Private environment: {info.get('probe', 'ready') if ready else 'not set up'} ({private})")
    if job is not None and job.state == "failed":
        draw_error(box, job.message)
    elif job is not None and job.message:
        col.label(text=job.message.splitlines()[0], icon="CHECKMARK" if job.state == "done" else "INFO")


class NerfBridgePreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    python_path: StringProperty(
        name="Python with torch",
        description="Interpreter that runs training and rendering (it must be able to import torch), "
        "e.g. the private environment Set up PyTorch makes, or the project's .venv/bin/python. Empty: "
        "Blender's own Python, if it has torch",
        subtype="FILE_PATH",
        default="",
    )
    torch_device: EnumProperty(name="PyTorch build", items=DEVICE_ITEMS, default=torch_setup.default_device(),
                               description="CPU runs everywhere; CUDA needs an NVIDIA GPU and driver "
                               "(the default follows what this machine has)")
    wheel_dir: StringProperty(name="Install from folder", subtype="DIR_PATH", default="",
                              description="A folder of .whl files (from `pip download`) to install from, offline; "
                              "empty: download")
    torch_openexr: BoolProperty(name="Also install OpenEXR (EXR datasets, ~5 MB)", default=True)
    found: CollectionProperty(type=NerfFoundPython)

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "python_path")
        row = layout.row()
        row.label(text="Training runs in this interpreter as a separate process; Blender never loads torch.",
                  icon="INFO")
        row = layout.row()
        row.operator(NERF_OT_check_python.bl_idname, icon="CHECKMARK")
        row.operator(NERF_OT_find_pythons.bl_idname, text="Find Interpreters", icon="VIEWZOOM")
        for item in self.found:
            row = layout.row()
            row.label(text=f"{item.label}: {item.message}", icon="CHECKMARK" if item.ok else "ERROR")
            sub = row.row()
            sub.enabled = item.ok and os.path.abspath(self.python_path or "-") != item.python
            sub.operator(NERF_OT_use_python.bl_idname).python = item.python
        draw_setup(layout, self)


CLASSES = (NERF_OT_check_python, NERF_OT_setup_torch, NERF_OT_setup_torch_cancel, NerfFoundPython,
           NERF_OT_find_pythons, NERF_OT_use_python, NerfBridgePreferences)
register, unregister = bpy.utils.register_classes_factory(CLASSES)
