"""Reliability rules (docs/RELIABILITY.md): resume on the right data, full disks, what --overwrite may
delete, run folders vs datasets, unique render names, one validator, early refusals of huge requests."""
import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from nerf_core.cli.main import main
from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.errors import TrainError
from nerf_core.runs.events import read_events

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _cfg(ds, run, **kw):
    base = dict(dataset=str(ds), out=str(run), method="test-grid", max_steps=6, batch_rays=64, seed=0,
                stdout_events=False, show_bar=False, log_every=5, eval_views=0)
    base.update(kw)
    return TrainConfig(**base)


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=REPO_ROOT, NERF_CORE_PLUGINS="nerf_core.tests.conftest")
    return subprocess.run([sys.executable, "-m", "nerf_core", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO_ROOT, env=env, timeout=300)


def _clear_error(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "error:" in last
    for w in words:
        assert str(w) in last, (w, last)
    return last


# ---------------------------------------------------------------------------------------------- 1. resume


def test_resume_on_another_dataset_is_refused_naming_both(sphere_dataset, dataset_factory, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run))
    cfg = json.loads((run / "config.json").read_text())
    assert len(cfg["dataset_hash"]) == 64
    other = dataset_factory(tmp_path / "other", n_train=5)
    proc = _cli("train", other, "--out", run, "--resume", "--max-steps", "8", "--no-bar")
    _clear_error(proc, "trained on", str(sphere_dataset.resolve()), str(other.resolve()))
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=False)["step"] == 6  # untouched


def test_resume_on_a_moved_dataset_is_accepted_by_its_hash(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run))
    moved = tmp_path / "moved"
    shutil.move(str(sphere_dataset), str(moved))
    out = train(_cfg(moved, run, max_steps=9, resume=True))
    assert out["step"] == 9
    assert json.loads((run / "config.json").read_text())["dataset"] == str(moved.resolve())


def test_resume_on_a_changed_dataset_at_the_same_path_is_refused(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run))
    tj = sphere_dataset / "transforms_train.json"
    meta = json.loads(tj.read_text())
    meta["frames"] = meta["frames"][:-1]
    tj.write_text(json.dumps(meta))
    with pytest.raises(TrainError, match="dataset changed since the run started"):
        train(_cfg(sphere_dataset, run, max_steps=9, resume=True))


def test_old_run_without_hash_needs_dataset_moved(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run))
    for name in ("latest.pt", "step_0000006.pt"):
        ck = torch.load(run / "checkpoints" / name, weights_only=False)
        ck["config"].pop("dataset_hash")
        torch.save(ck, run / "checkpoints" / name)
    moved = tmp_path / "moved"
    shutil.copytree(sphere_dataset, moved)
    with pytest.raises(TrainError, match="--dataset-moved"):
        train(_cfg(moved, run, max_steps=8, resume=True))
    assert train(_cfg(moved, run, max_steps=8, resume=True, dataset_moved=True))["step"] == 8


class _Killed(BaseException):
    """Stands for SIGKILL: nothing in the trainer catches it."""


def test_run_killed_before_its_first_checkpoint_can_be_restarted_as_the_message_says(
    sphere_dataset, tmp_path, monkeypatch
):
    from nerf_core.methods.registry import method_class

    def hook(self, step, frac):
        if step == 2:
            raise _Killed
        return False

    monkeypatch.setattr(method_class("test-grid"), "training_hook", hook)
    run = tmp_path / "run"
    with pytest.raises(_Killed):
        train(_cfg(sphere_dataset, run, preview_every=1))
    monkeypatch.undo()
    assert (run / "config.json").is_file() and not (run / "checkpoints" / "latest.pt").exists()
    proc = _cli(
        "train", sphere_dataset, "--out", run, "--method", "test-grid", "--resume", "--max-steps", "3", "--no-bar"
    )
    last = _clear_error(proc, "latest.pt", "before its first checkpoint", "--overwrite")
    proc = _cli("train", sphere_dataset, "--out", run, "--method", "test-grid", "--overwrite", "--max-steps", "3",
                "--no-bar", "--eval-views", "0")
    assert proc.returncode == 0, proc.stderr + last
    assert torch.load(run / "checkpoints" / "latest.pt", weights_only=False)["step"] == 3


# ---------------------------------------------------------------------------------------------- 2. disk full


def test_disk_full_at_checkpoint_is_a_clear_error_and_resume_uses_the_newest_complete_checkpoint(
        sphere_dataset, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=4))
    real_save = torch.save

    def full_disk_save(obj, f, *a, **k):
        name = getattr(f, "name", f)  # utils.atomic hands torch.save the open temporary file
        if ".latest.pt." in str(name):
            f.write(b"PK\x03\x04partial")  # a partial file, as a full disk leaves it
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(name))
        return real_save(obj, f, *a, **k)

    monkeypatch.setattr(torch, "save", full_disk_save)
    rc = main(["train", str(sphere_dataset), "--out", str(run), "--resume", "--max-steps", "8", "--no-bar"])
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert "latest.pt" in err and "no space left on device" in err
    last = read_events(run / "progress.jsonl")[-1]
    assert last["event"] == "error" and "no space left on device" in last["message"] and "latest.pt" in last["message"]
    ck = run / "checkpoints"
    assert not list(ck.glob("*.tmp"))  # no half-written file left behind
    assert torch.load(ck / "step_0000008.pt", weights_only=False)["step"] == 8
    (ck / "latest.pt").unlink()  # as an older trainer left it: latest.pt missing, step_*.pt complete
    out = train(_cfg(sphere_dataset, run, max_steps=10, resume=True))
    assert out["step"] == 10
    starts = [e for e in read_events(run / "progress.jsonl") if e["event"] == "start"]
    assert starts[-1]["resumed_from"] == 8


def test_disk_full_on_rename_is_reported_too(sphere_dataset, tmp_path, monkeypatch):
    import nerf_core.utils.atomic as tr  # the one home of write-then-rename

    real_replace = os.replace

    def full(src, dst, *a, **k):
        if str(dst).endswith(".pt"):
            raise OSError(errno.ENOSPC, "No space left on device", str(src))
        return real_replace(src, dst, *a, **k)

    monkeypatch.setattr(tr.os, "replace", full)
    with pytest.raises(TrainError, match=r"step_0000003\.pt: cannot write checkpoint: no space left on device"):
        train(_cfg(sphere_dataset, tmp_path / "run", max_steps=3))
    monkeypatch.undo()
    assert not list((tmp_path / "run" / "checkpoints").glob("*.tmp"))


def test_resume_skips_a_damaged_latest(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=4))
    (run / "checkpoints" / "latest.pt").write_bytes(b"truncated")
    assert train(_cfg(sphere_dataset, run, max_steps=6, resume=True))["step"] == 6


# ---------------------------------------------------------------------------------------------- 3. overwrite


def test_overwrite_removes_only_files_the_trainer_recorded(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=4, preview_every=2, eval_views=1))
    written = json.loads((run / ".written.json").read_text())
    assert {"config.json", "progress.jsonl", "metrics.json", "checkpoints/latest.pt"} <= set(written)
    (run / "checkpoints" / "my_best_model.pt").write_bytes(b"mine")
    (run / "previews" / "step_0999999.png").write_bytes(b"mine too")  # trainer-like name, not on the list
    (run / ".lock").write_text("12345\n")
    train(_cfg(sphere_dataset, run, max_steps=2, overwrite=True))
    assert (run / "checkpoints" / "my_best_model.pt").read_bytes() == b"mine"
    assert (run / "previews" / "step_0999999.png").read_bytes() == b"mine too"
    assert not (run / "checkpoints" / "step_0000004.pt").exists()


def test_overwrite_of_a_run_without_a_list_removes_only_exact_trainer_names(sphere_dataset, tmp_path):
    run = tmp_path / "run"
    train(_cfg(sphere_dataset, run, max_steps=3))
    (run / ".written.json").unlink()
    for name in (
        "checkpoints/my_best_model.pt",
        "checkpoints/latest.pt.bak",
        "previews/step_1.png",
        "config.json.orig",
    ):
        (run / name).write_bytes(b"mine")
    train(_cfg(sphere_dataset, run, max_steps=2, overwrite=True))
    for name in (
        "checkpoints/my_best_model.pt",
        "checkpoints/latest.pt.bak",
        "previews/step_1.png",
        "config.json.orig",
    ):
        assert (run / name).read_bytes() == b"mine", name
    assert not (run / "checkpoints" / "step_0000003.pt").exists()


def test_overwrite_of_a_folder_that_is_not_a_run_deletes_nothing(sphere_dataset, tmp_path):
    # A user's project folder with files that share a run's names, but no .written.json and a
    # config.json that is not a trainer's: --overwrite must neither delete nor write over them.
    folder = tmp_path / "project"
    folder.mkdir()
    mine = {"config.json": '{"my": "project settings"}', "metrics.json": "{}", "progress.jsonl": "x\n",
            "notes.txt": "keep"}
    for name, text in mine.items():
        (folder / name).write_text(text)
    proc = _cli("train", sphere_dataset, "--out", folder, "--method", "test-grid", "--max-steps", "2", "--no-bar",
                "--overwrite")
    _clear_error(proc, str(folder), "not a run folder", "config.json")
    for name, text in mine.items():
        assert (folder / name).read_text() == text, name
    # A folder with only unrelated files is fine: the run goes beside them.
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    train(_cfg(sphere_dataset, other, max_steps=2, overwrite=True))
    assert (other / "notes.txt").read_text() == "keep" and (other / "checkpoints" / "latest.pt").is_file()


# ---------------------------------------------------------------------------------------------- 4. out vs dataset


@pytest.mark.parametrize("where", ["same", "inside", "contains"])
def test_run_folder_and_dataset_must_be_apart(dataset_factory, tmp_path, where):
    if where == "contains":
        ds = dataset_factory(tmp_path / "run" / "ds")
        out = tmp_path / "run"
    else:
        ds = dataset_factory(tmp_path / "ds")
        out = ds if where == "same" else ds / "run"
    before = sorted(p.name for p in ds.rglob("*"))
    proc = _cli("train", ds, "--out", out, "--method", "test-grid", "--max-steps", "2", "--no-bar")
    _clear_error(proc, "--out", str(out.resolve()))
    assert sorted(p.name for p in ds.rglob("*")) == before  # not even a lock file


@pytest.mark.parametrize("command", ["train", "render"])
@pytest.mark.parametrize("under", [False, True])
def test_an_output_path_through_a_file_names_the_file(sphere_dataset, trained_run, tmp_path, command, under):
    """`--out notes.txt` or `--out notes.txt/run`: the file is named and left alone, with no [Errno ...]."""
    blocker = tmp_path / "notes.txt"
    blocker.write_text("keep")
    out = blocker / "run" if under else blocker
    args = (["train", sphere_dataset, "--method", "test-grid", "--max-steps", "2", "--no-bar"] if command == "train"
            else ["render", trained_run["run"]])
    proc = _cli(*args, "--out", out)
    last = _clear_error(proc, "notes.txt is a file, and a folder is needed there")
    assert "[Errno" not in last and blocker.read_text() == "keep"


# ---------------------------------------------------------------------------------------------- 5. render names


def _camera_list(names, w=8, h=6):
    from nerf_core.tests.conftest import look_at

    return [{"name": n, "transform_matrix": look_at((3.0, 0.2 * k, 1.0)).tolist(), "w": w, "h": h,
             "camera_angle_x": 0.8} for k, n in enumerate(names)]


@pytest.mark.parametrize("names", [["a", "a", "a_1"], ["a_1", "a", "a"], ["x", "X", "x_1", "x"], ["", "view_000", ""]])
def test_render_names_are_unique_for_any_collision(trained_run, tmp_path, names):
    from nerf_core.contract.naming import unique_stems

    stems = unique_stems(names)
    assert len({s.lower() for s in stems}) == len(names)
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps(_camera_list(names)))
    proc = _cli("render", trained_run["run"], "--cameras", cams, "--out", tmp_path / "out", "--no-bar")
    assert proc.returncode == 0, proc.stderr
    meta = json.loads((tmp_path / "out" / "renders.json").read_text())
    files = [f["file_path"] for f in meta["frames"]]
    assert len(files) == len(set(files)) == len(names)
    assert len(list((tmp_path / "out").glob("*.png"))) == len(names)


# ---------------------------------------------------------------------------------------------- 7. huge requests


def test_render_refuses_a_huge_view_with_its_memory_estimate(trained_run, tmp_path):
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps(_camera_list(["small", "huge"])[:1] + _camera_list(["huge"], w=60000, h=60000)))
    proc = _cli("render", trained_run["run"], "--cameras", cams, "--out", tmp_path / "out", "--no-bar")
    _clear_error(proc, "60000x60000", "GB", "--downscale")
    assert not (tmp_path / "out").exists()  # refused before anything was written
    proc = _cli("render", trained_run["run"], "--cameras", trained_run["dataset"], "--out", tmp_path / "o2",
                "--downscale", "0.0001", "--no-bar")
    _clear_error(proc, "GB")


def test_eval_refuses_a_downscale_that_leaves_no_pixels(trained_run):
    proc = _cli("eval", trained_run["run"], "--downscale", "100000", "--no-bar")
    _clear_error(proc, "r_0.png", "--downscale")


# ---------------------------------------------------------------------------------------------- 6. one validator


def _truncate_png(ds):
    p = ds / "train" / "r_1.png"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    return "r_1"


def _corrupt_depth(ds):
    (ds / "train" / "r_2_depth.exr").write_bytes(b"\x76\x2f\x31\x01 not really an exr")
    return "r_2_depth.exr"


def _small_depth(ds):
    import numpy as np

    from nerf_core.image.io import write_exr

    write_exr(ds / "train" / "r_2_depth.exr", {"Z": np.ones((5, 7), np.float32)})
    return "depth_file_path"


def _set_near_far(ds, near, far):
    """The same near/far in every split file."""
    for split in ("train", "val", "test"):
        p = ds / f"transforms_{split}.json"
        meta = json.loads(p.read_text())
        meta["near"], meta["far"] = near, far
        p.write_text(json.dumps(meta))


def _far_before_near(ds):
    _set_near_far(ds, 5.0, 1.0)
    return "'far'"


def _one_train_frame(ds):
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["frames"] = meta["frames"][:1]
    p.write_text(json.dumps(meta))
    return "train split has 1 view"


def _fov_beyond_pi(ds):
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["camera_angle_x"] = 4.0
    for k in ("fl_x", "fl_y"):
        meta.pop(k)
    p.write_text(json.dumps(meta))
    return "camera_angle_x"


def _near_is_text(ds):
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["near"] = "two"
    p.write_text(json.dumps(meta))
    return "near"


def _camera_far_out(ds):
    # Finite, so the NaN/inf rule lets it through; float32 cannot resolve a scene 1e30 units out.
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["frames"][3]["transform_matrix"][0][3] = 1e30
    p.write_text(json.dumps(meta))
    return "frame 3 (./train/r_3): field 'transform_matrix': the camera position reaches 1e+30 units"


def _huge_box(ds):
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["aabb"] = [[-1e30] * 3, [1e30] * 3]
    p.write_text(json.dumps(meta))
    return "field 'aabb': the box reaches 1e+30 units"


def _flat_box(ds):
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["aabb"] = [[-1, -1, 0], [1, 1, 1e-9]]
    p.write_text(json.dumps(meta))
    return "field 'aabb' is 1e-09 units thick along z"


def _edit_train(ds, fn):
    p = ds / "transforms_train.json"
    meta = json.loads(p.read_text())
    fn(meta)
    p.write_text(json.dumps(meta))


def _tiny_focal(ds):
    # 1e-300 px is a positive finite number, but 0 in float32: every ray direction turned NaN and
    # train still exited 0 with PSNR numbers.
    _edit_train(ds, lambda m: m.update(fl_x=1e-300))
    return "field 'fl_x' is a focal length in pixels and must lie in [0.001, 1e+08]"


def _focal_as_text(ds):
    _edit_train(ds, lambda m: m.update(fl_x="44.4"))  # numpy read "44.4" as a number
    return "field 'fl_x' is not a number ('44.4')"


def _lone_width(ds):
    # 'w' of twice the image width without 'h' halved the focal length silently.
    def edit(m):
        m["w"] = 48
        m.pop("h")
    _edit_train(ds, edit)
    return "fields 'w'/'h' say 48x? but"


def _empty_masks(ds):
    # Every loss term weighted by 0: train exited 0 with loss 0.0 and no PSNR at every step.
    from PIL import Image

    def edit(m):
        for k, fr in enumerate(m["frames"]):
            Image.new("L", (24, 20), 0).save(ds / "train" / f"r_{k}_mask.png")
            fr["mask_path"] = f"train/r_{k}_mask.png"
    _edit_train(ds, edit)
    return "field 'mask_path': the masks of all 8 train frames that have one are empty"


def _one_image_twice(ds):
    # Two frames of one image (one pose) passed the at-least-2-views rule.
    _edit_train(ds, lambda m: m.update(frames=[m["frames"][0], dict(m["frames"][0])]))
    return "train split has 1 view"


def _far_at_1e300(ds):
    _edit_train(ds, lambda m: m.update(near=1e299, far=1e300))
    return "field 'near' reaches 1e+299 units"


def _near_far_short_of_the_box(ds):
    # Cameras 3 units out, a box of +-1: a far of 0.5 keeps every sample 1.5 units short of it.
    _set_near_far(ds, 0.0, 0.5)
    return "fields 'near'/'far' (0.0 to 0.5) never reach the scene box"


def _all_transparent(ds):
    # Cameras that all look past the subject: check said "valid" and train exited 0 having learnt nothing.
    from PIL import Image

    for png in (ds / "train").glob("r_*.png"):
        Image.new("RGBA", Image.open(png).size, (0, 0, 0, 0)).save(png)
    return "train images are fully transparent"


def _all_black(ds):
    # Cameras standing inside one closed object (the 'inside' layout on a lone cube), or the lights off:
    # opaque black everywhere. check said "valid" and train learnt a black fog.
    from PIL import Image

    for png in (ds / "train").glob("r_*.png"):
        Image.new("RGBA", Image.open(png).size, (0, 0, 0, 255)).save(png)
    return "train images are opaque and black everywhere"


BROKEN = [_truncate_png, _corrupt_depth, _small_depth, _far_before_near, _one_train_frame, _fov_beyond_pi,
          _near_is_text, _camera_far_out, _huge_box, _flat_box, _tiny_focal, _focal_as_text, _lone_width,
          _empty_masks, _one_image_twice, _far_at_1e300, _near_far_short_of_the_box, _all_transparent, _all_black]


@pytest.mark.parametrize("breaker", BROKEN, ids=lambda f: f.__name__.strip("_"))
def test_check_rejects_what_train_rejects(dataset_factory, tmp_path, breaker, capsys):
    ds = dataset_factory(tmp_path / "ds")
    word = breaker(ds)
    from nerf_core.check.dataset import check_dataset
    from nerf_core.data.problems import dataset_problems

    report = check_dataset(ds)
    assert not report.ok
    assert any(word in str(p) for p in report.errors), [str(p) for p in report.errors]
    assert dataset_problems(ds)
    rc = main(["check", str(ds)])
    out = capsys.readouterr().out
    assert rc == 1 and word in out
    rc = main(
        ["train", str(ds), "--out", str(tmp_path / "run"), "--method", "test-grid", "--max-steps", "2", "--no-bar"]
    )
    err = capsys.readouterr().err
    assert rc == 2 and word in err.strip().splitlines()[-1] and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_check_lists_every_loader_problem_and_train_stops_at_the_first(dataset_factory, tmp_path):
    from nerf_core.check.dataset import check_dataset
    from nerf_core.contract.errors import DatasetError
    from nerf_core.data.loading import load_dataset
    from nerf_core.data.problems import dataset_problems

    ds = dataset_factory(tmp_path / "ds")
    _truncate_png(ds)
    _corrupt_depth(ds)
    problems = dataset_problems(ds)
    assert len(problems) == 2 and "r_1" in problems[0] and "r_2_depth.exr" in problems[1]
    with pytest.raises(DatasetError) as exc:
        load_dataset(ds)
    assert str(exc.value) == problems[0]
    text = "\n".join(str(p) for p in check_dataset(ds).errors)
    assert "r_1" in text and "r_2_depth.exr" in text


def test_train_images_that_all_fail_to_load_are_not_also_called_transparent(dataset_factory, tmp_path):
    # Every train frame failing (images deleted, masks unreadable) left "shows something" unknown, and
    # check added "all 8 train images are fully transparent" to the real errors.
    from nerf_core.data.problems import dataset_problems

    ds = dataset_factory(tmp_path / "ds", layouts=("synthetic",))
    for png in (ds / "train").glob("r_*.png"):
        png.unlink()
    problems = dataset_problems(ds)
    assert len(problems) == 8 and all("not found" in p for p in problems), problems
    assert not any("fully transparent" in p for p in problems)


def test_a_valid_dataset_passes_both(sphere_dataset):
    from nerf_core.check.dataset import check_dataset
    from nerf_core.data.problems import dataset_problems

    assert check_dataset(sphere_dataset).ok and dataset_problems(sphere_dataset) == []


def test_paths_outside_the_dataset_are_read_with_a_note_and_bad_path_types_are_refused(tmp_path, dataset_factory):
    """One policy for every path field (data.resolve_dataset_path): absolute and '../' paths are read
    but reported, in train's notes and as check warnings; a path that is not a string is refused."""
    import shutil

    from nerf_core.check.dataset import check_dataset
    from nerf_core.contract.errors import DatasetError
    from nerf_core.data.loading import load_dataset

    ds = dataset_factory(tmp_path / "ds", layouts=("synthetic",))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    shutil.copy(ds / "train" / "r_0.png", elsewhere / "r_0.png")
    shutil.copy(ds / "train" / "r_0_depth.exr", elsewhere / "d0.exr")
    meta = json.loads((ds / "transforms_train.json").read_text())
    meta["frames"][0]["file_path"] = "../elsewhere/r_0"
    meta["frames"][0]["depth_file_path"] = str(elsewhere / "d0.exr")  # absolute
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    data = load_dataset(ds)
    assert any("outside the dataset folder" in n and "2 file path(s)" in n for n in data.notes)
    report = check_dataset(ds)
    outside = [str(w) for w in report.warnings if "outside the dataset folder" in str(w)]
    assert len(outside) == 2 and any("depth_file_path" in w for w in outside)
    meta["frames"][1]["mask_path"] = 7
    (ds / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(
        DatasetError,
        match=r"transforms_train.json: frame 1 \(./train/r_1\): field 'mask_path' must be a non-empty string",
    ):
        load_dataset(ds)


# ---------------------------------------------------------------------------------------------- malformed files


def test_json_nested_too_deeply_is_named_not_a_recursion_traceback(sphere_dataset, trained_run, tmp_path):
    deep = "[" * 200_000 + "]" * 200_000
    meta = json.loads((sphere_dataset / "transforms_train.json").read_text())
    (sphere_dataset / "transforms_train.json").write_text(json.dumps(meta)[:-1] + ', "junk": ' + deep + "}")
    for proc in (_cli("check", sphere_dataset), _cli("train", sphere_dataset, "--out", tmp_path / "run",
                                                     "--method", "test-grid", "--max-steps", "2", "--no-bar")):
        said = proc.stdout + proc.stderr  # check reports on stdout, train on stderr
        assert proc.returncode != 0 and "Traceback" not in said, said[-2000:]
        assert "transforms_train.json" in said and "nested too deeply" in said
    cams = tmp_path / "cams.json"
    cams.write_text(deep)
    _clear_error(_cli("render", trained_run["run"], "--cameras", cams, "--out", tmp_path / "r"), str(cams), "nested")


def test_a_camera_file_holding_a_bare_value_is_named(trained_run, tmp_path):
    cams = tmp_path / "cams.json"
    cams.write_text('"hello"')
    _clear_error(_cli("render", trained_run["run"], "--cameras", cams, "--out", tmp_path / "r"), str(cams),
                 "expected a list of cameras")


def test_an_image_in_a_symlink_loop_is_named_by_check(sphere_dataset):
    img = sphere_dataset / "train" / "r_3.png"
    img.unlink()
    os.symlink(sphere_dataset / "train" / "x.png", img)
    os.symlink(img, sphere_dataset / "train" / "x.png")
    proc = _cli("check", sphere_dataset)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-2000:]
    assert "frame 3" in proc.stdout and "r_3.png" in proc.stdout


@pytest.mark.parametrize("command", ["eval", "render", "serve"])
def test_a_run_whose_config_is_not_an_object_is_named(trained_run, tmp_path, command):
    import shutil

    run = Path(shutil.copytree(trained_run["run"], tmp_path / "run"))
    (run / "config.json").write_text("[]")
    args = [command, run] + (["--out", tmp_path / "r"] if command == "render" else [])
    _clear_error(_cli(*args), str(run / "config.json"), "expected the JSON object")


@pytest.mark.parametrize("edit, field", [
    ({"camera_model": "EQUIRECTANGULAR"}, "camera_model"),
    ({"camera_model": "FULL_OPENCV", "k5": 0.01}, "camera_model"),
    ({"camera_model": "OPENCV", "k5": 0.01}, "k5"),
    ({"camera_model": "OPENCV", "p2": "abc"}, "p2"),
    ({"camera_model": "OPENCV_FISHEYE", "p1": 0.01}, "p1"),
    ({"camera_model": "OPENCV", "k1": -3.0}, "k1"),  # folds back inside the image
])
def test_cameras_whose_lens_cannot_be_read_are_refused(sphere_dataset, tmp_path, edit, field):
    # OPENCV and OPENCV_FISHEYE are undistorted per pixel (test_lens.py); any other model, or
    # coefficients that cannot be read or undone, would bend rays in silence, so they are refused by name.
    path = sphere_dataset / "transforms_train.json"
    meta = json.loads(path.read_text())
    meta["frames"][1].update(edit)
    path.write_text(json.dumps(meta))
    proc = _cli("check", sphere_dataset)
    assert proc.returncode == 1 and "frame 1 (./train/r_1): field" in proc.stdout and repr(field) in proc.stdout, (
        proc.stdout
    )
    _clear_error(_cli("train", sphere_dataset, "--out", tmp_path / "run", "--method", "test-grid", "--max-steps", "2",
                      "--no-bar"), "transforms_train.json", "frame 1", repr(field))


def test_an_opencv_camera_with_zero_distortion_is_a_pinhole(sphere_dataset):
    path = sphere_dataset / "transforms_train.json"
    meta = json.loads(path.read_text())
    meta.update({"camera_model": "OPENCV", "k1": 0.0, "k2": 0, "p1": 0.0, "p2": 0.0})
    path.write_text(json.dumps(meta))
    proc = _cli("check", sphere_dataset)
    assert proc.returncode == 0, proc.stdout


@pytest.mark.parametrize("args, named", [
    (["--method", "vmgrid", "--set", "res_init=-5"], "option 'res_init'"),
    (["--method", "vmgrid", "--set", "step_ratio=nan"], "option 'step_ratio'"),
    (["--method", "vmgrid", "--set", "upsample_at=hello"], "option 'upsample_at'"),
    (["--method", "vmgrid", "--set", "upsample_at=[0.9,0.1,5]"], "option 'upsample_at'"),
    (["--method", "vmgrid", "--set", "unbounded=maybe"], "option 'unbounded'"),
    (["--method", "vmgrid", "--set", "density_rank=true"], "option 'density_rank'"),
    (["--method", "vmgrid", "--set", "res_final=100000"], "option 'res_final'"),
    (["--method", "nerf", "--set", "width=0"], "option 'width'"),
    (["--method", "nerf", "--set", "pos_freqs=-3"], "option 'pos_freqs'"),
    (["--method", "test-grid", "--lr", "inf"], "--lr"),
    (["--method", "test-grid", "--max-seconds", "nan"], "--max-seconds"),
    (["--method", "test-grid", "--seed", "1180591620717411303424"], "--seed"),
    (["--method", "test-grid", "--batch-rays", "1000000000000"], "--batch-rays"),
    (["--method", ""], "--method"),
    (["--method", "nope"], "unknown method 'nope'"),
    (["--method", "vmgrid", "--set", "bogus=1"], "unknown options ['bogus']"),
])
def test_bad_options_and_flags_are_named_before_the_run_folder_is_made(sphere_dataset, tmp_path, args, named):
    out = tmp_path / "run"
    proc = _cli("train", sphere_dataset, "--out", out, "--max-steps", "2", "--no-bar", *args)
    _clear_error(proc, named)
    assert not out.exists()  # fixing the flag and running again needs no --overwrite


def test_eval_at_refuses_empty_and_non_finite_times(sphere_dataset, tmp_path):
    for value in ("5,,6", "nan", "inf"):
        proc = _cli("train", sphere_dataset, "--out", tmp_path / "run", "--method", "test-grid", "--eval-at", value)
        assert proc.returncode == 2 and "--eval-at" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    "edit, named",
    [
        (lambda m: m.update(w=m["w"] * 2, h=m["h"] * 2), "fields 'w'/'h'"),
        (lambda m: m.update(w=m["w"] + 0.5), "field 'w'"),
        (
            lambda m: m["frames"][1].update(
                transform_matrix=[[str(v) for v in row] for row in m["frames"][1]["transform_matrix"]]
            ),
            "field 'transform_matrix'",
        ),
        (lambda m: m["frames"][1].update(file_path="./train/r_1\x00.png"), "field 'file_path'"),
    ],
)
def test_sizes_strings_and_nul_bytes_are_refused_at_any_downscale(sphere_dataset, tmp_path, edit, named):
    path = sphere_dataset / "transforms_train.json"
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))
    check = _cli("check", sphere_dataset)
    # check names a wrong size by what it contradicts (the image's size, camera_angle_x): the frame.
    assert check.returncode == 1 and "Traceback" not in check.stdout + check.stderr
    assert (named if "/" not in named else "frame 0 (./train/r_0)") in check.stdout
    for downscale in ("1", "2"):  # a wrong w/h used to be rescaled in silence at --downscale 2
        _clear_error(_cli("train", sphere_dataset, "--out", tmp_path / f"run{downscale}", "--method", "test-grid",
                          "--max-steps", "1", "--no-bar", "--downscale", downscale), "transforms_train.json", named)


def test_one_image_named_by_two_frames_with_different_poses_is_refused(sphere_dataset, tmp_path):
    path = sphere_dataset / "transforms_train.json"
    meta = json.loads(path.read_text())
    meta["frames"][4]["file_path"] = meta["frames"][3]["file_path"]  # frame 4 keeps its own pose
    path.write_text(json.dumps(meta))
    check = _cli("check", sphere_dataset)
    assert check.returncode == 1 and "frame 4" in check.stdout and "same image as frame 3" in check.stdout
    _clear_error(_cli("train", sphere_dataset, "--out", tmp_path / "run", "--method", "test-grid", "--max-steps", "1",
                      "--no-bar"), "frame 4", "same image as frame 3")
    # The same image with the same pose twice is a harmless repeat.
    meta["frames"][4]["transform_matrix"] = meta["frames"][3]["transform_matrix"]
    path.write_text(json.dumps(meta))
    assert "same image" not in _cli("check", sphere_dataset).stdout


def test_running_out_of_memory_names_the_settings_to_lower(sphere_dataset, tmp_path, monkeypatch):
    from nerf_core.errors import TrainError
    from nerf_core.tests.conftest import TinyGrid

    def no_memory(self, *a, **k):
        raise RuntimeError("[enforce fail at alloc_cpu.cpp:127] data. DefaultCPUAllocator: not enough memory: "
                           "you tried to allocate 4000000000000000 bytes.")

    monkeypatch.setattr(TinyGrid, "render_rays", no_memory)
    with pytest.raises(TrainError) as err:
        train(_cfg(sphere_dataset, tmp_path / "run"))
    msg = str(err.value)
    assert "training failed at step" in msg and "not enough memory" in msg and "--batch-rays (now 64)" in msg
    assert "4000000000000000 bytes" in msg  # the allocator's own words stay, shortened


def test_progress_file_inside_the_dataset_or_not_a_log_is_refused_untouched(sphere_dataset, tmp_path, capsys):
    # --progress appended events to whatever file it named: the dataset's own transforms file, an image.
    target = sphere_dataset / "transforms_train.json"
    before = target.read_bytes()
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    for path, words in ((target, "lies inside the dataset folder"), (notes, "is not a progress log")):
        rc = main(["train", str(sphere_dataset), "--out", str(tmp_path / "run"), "--method", "test-grid",
                   "--max-steps", "2", "--no-bar", "--progress", str(path)])
        err = capsys.readouterr().err
        assert rc == 2 and words in err.strip().splitlines()[-1] and "Traceback" not in err
    assert target.read_bytes() == before and notes.read_text() == "my notes\n"
    assert not (tmp_path / "run").exists()
    log = tmp_path / "log.jsonl"  # a log of an earlier run is appended to
    for extra in ([], ["--resume", "--max-steps", "4"]):
        assert main(["train", str(sphere_dataset), "--out", str(tmp_path / "ok"), "--method", "test-grid",
                     "--max-steps", "2", "--no-bar", "--progress", str(log), *extra]) == 0
    assert sum(e["event"] == "done" for e in read_events(log)) == 2


def test_resume_refuses_settings_it_would_ignore(sphere_dataset, tmp_path, capsys):
    # --lr, --set, --seed ... with --resume exited 0 and trained with the run's own values.
    run = tmp_path / "run"
    assert main(["train", str(sphere_dataset), "--out", str(run), "--method", "test-grid", "--max-steps", "2",
                 "--no-bar", "--lr", "0.01"]) == 0
    capsys.readouterr()
    rc = main(["train", str(sphere_dataset), "--out", str(run), "--resume", "--max-steps", "4", "--no-bar",
               "--lr", "0.5", "--seed", "9"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 2 and "--lr 0.5 (the run's: 0.01)" in err and "--seed 9 (the run's: 0)" in err
    # Budgets, logging and the same values as the run's are fine.
    assert main(["train", str(sphere_dataset), "--out", str(run), "--resume", "--max-steps", "4", "--no-bar",
                 "--lr", "0.01", "--log-every", "1"]) == 0


@pytest.mark.parametrize("key, value, want", [
    ("eval_background", "white", "an RGB colour"),
    ("eval_background", [1, 1], "an RGB colour"),
    ("dataset", 5, "the dataset's path"),
    ("downscale", "x", "a whole number >= 1"),
])
@pytest.mark.parametrize("command", ["eval", "render"])
def test_a_run_config_with_damaged_fields_is_named(trained_run, tmp_path, command, key, value, want):
    run = Path(shutil.copytree(trained_run["run"], tmp_path / "run"))
    cfg = json.loads((run / "config.json").read_text())
    cfg[key] = value
    (run / "config.json").write_text(json.dumps(cfg))
    args = [command, run] + (["--out", tmp_path / "r"] if command == "render" else [])
    _clear_error(_cli(*args), "config.json", f"field {key!r} must be {want}")


def test_nerfstudio_split_lists_of_the_wrong_kind_are_named(sphere_dataset, capsys):
    p = sphere_dataset / "nerfstudio" / "transforms.json"
    original = json.loads(p.read_text())
    for value, words in (([5], "must be a list of file paths"), (5, "must be a list of file paths"),
                         ("train/r_0.png", "must be a list of file paths"),
                         (original["train_filenames"][:1] * 3, "lists '../train/r_0.png' twice")):
        p.write_text(json.dumps({**original, "train_filenames": value}))
        rc = main(["check", str(sphere_dataset / "nerfstudio")])
        out = capsys.readouterr()
        assert rc == 1 and "field 'train_filenames' " + words in out.out and "Traceback" not in out.err


def test_exr_images_with_nan_or_alpha_out_of_range_are_named(tmp_path):
    from nerf_core.contract.errors import DatasetError
    from nerf_core.data.loading import load_dataset
    from nerf_core.image.io import read_exr_rgba
    from nerf_core.tests.conftest import make_dataset, write_exr

    ds = make_dataset(tmp_path / "ds", exr_images=True, layouts=("synthetic",))
    img = ds / "train" / "r_2.exr"
    rgba = read_exr_rgba(img)
    for broken, words in ((("R", float("nan")), "1 pixel(s) with NaN or infinite values (the first at x=3, y=4)"),
                          (("A", 5.0), "has alpha 5 at x=3, y=4")):
        bad = rgba.copy()
        bad[4, 3, "RGBA".index(broken[0][0])] = broken[1]
        write_exr(img, {c: bad[..., j] for j, c in enumerate("RGBA")})
        with pytest.raises(DatasetError, match=r"frame 2 \(\./train/r_2\.exr\): field 'file_path': .*" + words.replace(
                "(", r"\(").replace(")", r"\)")):
            load_dataset(ds)
    bad = rgba.copy()
    bad[4, 3, 0] = -50.0  # negative light: clipped
    write_exr(img, {c: bad[..., j] for j, c in enumerate("RGBA")})
    assert float(load_dataset(ds).split("train").images[2, 4, 3, 0]) == 0.0


@pytest.mark.parametrize("command", ["train", "render"])
def test_an_empty_out_is_refused_not_the_current_folder(trained_run, sphere_dataset, tmp_path, command, monkeypatch,
                                                          capsys):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    args = ["train", str(sphere_dataset), "--method", "test-grid", "--max-steps", "2"] if command == "train" else [
        "render", str(trained_run["run"])]
    with pytest.raises(SystemExit) as exc:
        main([*args, "--out", "", "--no-bar"])
    assert exc.value.code == 2 and "argument --out: is empty" in capsys.readouterr().err
    assert os.listdir(cwd) == []


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="Linux special files")
def test_progress_to_special_files_works_or_is_named(sphere_dataset, tmp_path):
    # /dev/stdout on a pipe (as the add-on runs the trainer) resolved to /proc/PID/fd/pipe:[N];
    # /dev/full and /proc files failed with messages naming the run folder, or nothing.
    proc = _cli("train", sphere_dataset, "--out", tmp_path / "a", "--method", "test-grid", "--max-steps", "2",
                "--no-bar", "--progress", "/dev/stdout")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count('"event": "done"') == 2  # once for stdout, once through --progress
    _clear_error(_cli("train", sphere_dataset, "--out", tmp_path / "b", "--method", "test-grid", "--max-steps", "2",
                      "--no-bar", "--progress", "/proc/self/status"), "--progress /proc/self/status", "cannot append")
    proc = _cli("train", sphere_dataset, "--out", tmp_path / "c", "--method", "test-grid", "--max-steps", "2",
                "--no-bar", "--progress", "/dev/full")
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].endswith("/dev/full: no space left on device (at step 0)")
