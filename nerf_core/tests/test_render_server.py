"""``python -m nerf_core serve``: one model load, one JSON line per camera, images equal to ``render``'s."""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys

import numpy as np

from nerf_core.cameras.rays import Cameras
from nerf_core.render.server import RenderServer, parse_request
from nerf_core.render.frame import render_view
from nerf_core.runs.checkpoints import load_run
from nerf_core.tests.conftest import REPO_ROOT, look_at

C2W = look_at((0.5, -2.8, 1.2))


def _req(rid, out, **kw):
    base = {"id": rid, "c2w": C2W.tolist(), "fx": 22.0, "fy": 20.0, "cx": 11.0, "cy": 8.5, "w": 24, "h": 18,
            "out": str(out), "depth": True}
    base.update(kw)
    return base


def _serve(run, lines, progress=False, chunk=8192):
    """Run an in-process server over ``lines``; returns its events. ``progress`` events come from the
    clock (a frame slower than PROGRESS_EVERY_S, as on a loaded machine), so they are left out unless
    asked for."""
    out = io.StringIO()
    server = RenderServer(str(run), device="cpu", chunk=chunk, out=out)
    assert server.serve(io.StringIO("".join(line + "\n" for line in lines))) == 0
    events = [json.loads(x) for x in out.getvalue().splitlines()]
    return events if progress else [e for e in events if e["event"] != "progress"]


def test_a_slow_frame_reports_progress_chunk_by_chunk(trained_run, tmp_path, monkeypatch):
    monkeypatch.setattr("nerf_core.render.server.PROGRESS_EVERY_S", 0.0)  # every chunk is "slow"
    # 24 x 18 = 432 rays in chunks of 64: several progress events
    events = _serve(trained_run["run"], [json.dumps(_req(7, tmp_path / "p.npy"))], progress=True, chunk=64)
    kinds = [e["event"] for e in events]
    assert kinds[0] == "ready" and kinds[-1] == "result" and set(kinds[1:-1]) == {"progress"}
    prog = events[1:-1]
    assert all(e["id"] == 7 and e["total"] == 24 * 18 for e in prog)
    done = [e["done"] for e in prog]
    assert done == sorted(done) and done[-1] == 24 * 18 and len(done) >= 2
    assert [e["fraction"] for e in prog] == [round(d / (24 * 18), 4) for d in done]


def test_answers_match_render_view_pixel_for_pixel(trained_run, tmp_path):
    events = _serve(
        trained_run["run"],
        [
            json.dumps(_req(1, tmp_path / "a.npy")),
            json.dumps(
                _req(
                    2,
                    tmp_path / "b.npy",
                    c2w=C2W.reshape(-1).tolist(),
                    depth=False,
                    w=6,
                    h=5,
                    fx=5.5,
                    fy=5.0,
                    cx=None,
                    cy=None,
                )
            ),
        ],
    )
    assert [e["event"] for e in events] == ["ready", "result", "result"]
    assert events[0]["method"] == "test-grid" and events[0]["step"] == 30 and events[0]["background"] == "transparent"
    assert events[1]["path"] == str(tmp_path / "a.npy") and events[1]["depth_path"] == str(tmp_path / "a_depth.npy")
    assert events[2]["depth_path"] is None and not (tmp_path / "b_depth.npy").exists()

    # Independently: the same camera through render_view, with near/far from the run's config.
    model, config, _ = load_run(trained_run["run"], "cpu")
    cams = Cameras.create(C2W[None], 22.0, 20.0, 11.0, 8.5, 24, 18)
    ref = render_view(model, cams, 0, background=(0.0, 0.0, 0.0), near=config["near"], far=config["far"])
    rgba = np.load(tmp_path / "a.npy")
    depth = np.load(tmp_path / "a_depth.npy")
    assert rgba.dtype == np.float32 and rgba.shape == (18, 24, 4) and depth.shape == (18, 24)
    acc = ref["acc"].numpy()
    assert np.allclose(rgba[..., 3], acc, atol=1e-6)
    hit = acc > 1e-3
    assert hit.any() and np.allclose(rgba[..., :3][hit] * acc[hit][:, None], ref["rgb"].numpy()[hit], atol=1e-5)
    assert np.allclose(depth, ref["z_depth"].numpy(), atol=1e-5)
    small = np.load(tmp_path / "b.npy")
    assert small.shape == (5, 6, 4)  # cx, cy omitted: the image centre


def test_bad_requests_get_one_error_line_each_and_the_server_goes_on(trained_run, tmp_path):
    (tmp_path / "taken.npy").write_bytes(b"user data")
    lines = ["not json", json.dumps({"cmd": "dance"}), json.dumps(_req(3, tmp_path / "x.npy", fx=-1)),
             json.dumps(_req(4, tmp_path / "x.npy", c2w=[[1, 0], [0, 1]])),
             json.dumps(_req(5, tmp_path / "x.npy", w=0)), json.dumps(_req(6, "relative.npy")),
             json.dumps(_req(7, tmp_path / "taken.npy")), json.dumps(_req(8, tmp_path / "x.npy", near=3.0, far=2.0)),
             json.dumps(_req(9, tmp_path / "ok.npy")), json.dumps({"cmd": "quit"}),
             json.dumps(_req(10, tmp_path / "never.npy"))]
    events = _serve(trained_run["run"], lines)
    kinds = [e["event"] for e in events]
    assert kinds == ["ready"] + ["error"] * 8 + ["result"]
    msgs = [e["message"] for e in events[1:9]]
    assert "not JSON" in msgs[0] and "unknown cmd 'dance'" in msgs[1]
    assert msgs[2] == "request 3: field 'fx' must be positive, got -1"
    assert "request 4: field 'c2w' must be a 4x4 matrix" in msgs[3]
    assert "request 5: field 'w' must be a whole number of pixels" in msgs[4]
    assert "request 6: field 'out' must be an absolute path ending in .npy" in msgs[5]
    assert "taken.npy already exists" in msgs[6] and (tmp_path / "taken.npy").read_bytes() == b"user data"
    assert "'far' (2.0) must be greater than 'near' (3.0)" in msgs[7]
    assert [e["id"] for e in events[3:9]] == [3, 4, 5, 6, 7, 8]
    assert events[-1]["id"] == 9 and not (tmp_path / "never.npy").exists()  # nothing after quit


def test_values_float32_cannot_take_are_one_error_each_and_the_server_goes_on(trained_run, tmp_path):
    # A focal length of 1e-300 px (0 in float32) made NaN rays; the ValueError that followed ended the
    # server with exit 2 and no answer, and the next request was never served.
    text_c2w = [[str(v) for v in row] for row in C2W.tolist()]
    lines = [
        json.dumps(_req(1, tmp_path / "a.npy", fx=1e-300)),
        json.dumps(_req(2, tmp_path / "a.npy", cx=1e300)),
        json.dumps(_req(3, tmp_path / "a.npy", far=1e300)),
        json.dumps(_req(4, tmp_path / "a.npy", depth="no")),
        json.dumps(_req(5, tmp_path / "a.npy", c2w=text_c2w)),
        json.dumps(_req(6, str(tmp_path / "a") + "\0b.npy")),
        json.dumps(_req(7, tmp_path / "ok.npy")),
    ]
    events = _serve(trained_run["run"], lines)
    assert [e["event"] for e in events] == ["ready"] + ["error"] * 6 + ["result"]
    msgs = [e["message"] for e in events[1:7]]
    assert msgs[0] == "request 1: field 'fx' is a focal length in pixels and must lie in [0.001, 1e+08], got 1e-300"
    assert msgs[1] == "request 2: field 'cx' is 1e+300 pixels, beyond 1e+06"
    assert msgs[2].startswith("request 3: field 'far' reaches 1e+300 units from the origin")
    assert msgs[3] == "request 4: field 'depth' must be true or false, got 'no'"
    assert "request 5: field 'c2w': entries must be JSON numbers" in msgs[4]
    assert msgs[5] == "request 6: field 'out' holds a NUL character"
    assert not (tmp_path / "a.npy").exists() and np.load(tmp_path / "ok.npy").shape == (18, 24, 4)


def test_serve_refuses_a_chunk_that_renders_nothing(trained_run):
    env = {**os.environ, "NERF_CORE_PLUGINS": "nerf_core.tests.conftest", "PYTHONPATH": str(REPO_ROOT)}
    proc = subprocess.run([sys.executable, "-m", "nerf_core", "serve", str(trained_run["run"]), "--chunk", "0"],
                          input="", capture_output=True, text=True, env=env, timeout=120, cwd=str(REPO_ROOT))
    assert proc.returncode == 2 and "--chunk" in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stdout == ""


def test_a_request_that_is_json_but_not_an_object_is_answered_and_the_server_goes_on(trained_run, tmp_path):
    events = _serve(trained_run["run"], ["42", "[1, 2]", "null", '"text"', json.dumps(_req(1, tmp_path / "ok.npy"))])
    assert [e["event"] for e in events] == ["ready"] + ["error"] * 4 + ["result"]
    assert all("must be a JSON object" in e["message"] for e in events[1:5])
    assert "got int" in events[1]["message"] and "got list" in events[2]["message"]


def test_a_newer_request_of_the_same_group_replaces_a_waiting_one(trained_run, tmp_path):
    lines = [json.dumps(_req(k, tmp_path / f"v{k}.npy", group="viewport")) for k in (1, 2, 3)]
    lines.append(json.dumps(_req(4, tmp_path / "final.npy")))  # no group: always rendered
    out = io.StringIO()
    server = RenderServer(str(trained_run["run"]), device="cpu", out=out)
    for line in lines:  # all four are waiting before the first is handled; end of input comes after them
        server._inbox.put(line + "\n")
    assert server.serve(io.StringIO("")) == 0
    events = [json.loads(x) for x in out.getvalue().splitlines()][1:]
    assert [(e["event"], e["id"]) for e in events] == [("skipped", 1), ("skipped", 2), ("result", 3), ("result", 4)]
    assert not (tmp_path / "v1.npy").exists() and (tmp_path / "v3.npy").exists()


def test_a_line_nested_too_deeply_is_one_error_and_the_server_goes_on(trained_run, tmp_path):
    # json recurses once per level: 100 000 '[' raised RecursionError, which ended the server.
    events = _serve(trained_run["run"], ["[" * 100_000 + "]" * 100_000, json.dumps(_req(1, tmp_path / "ok.npy"))])
    assert [e["event"] for e in events] == ["ready", "error", "result"]
    assert "nested too deeply" in events[1]["message"]


def test_a_bad_newer_request_does_not_cancel_a_good_one(trained_run, tmp_path):
    lines = [json.dumps(_req(1, tmp_path / "v1.npy", group="viewport")),
             json.dumps(_req(2, tmp_path / "v2.npy", group="viewport", w=-5))]
    out = io.StringIO()
    server = RenderServer(str(trained_run["run"]), device="cpu", out=out)
    for line in lines:
        server._inbox.put(line + "\n")
    assert server.serve(io.StringIO("")) == 0
    events = [json.loads(x) for x in out.getvalue().splitlines()][1:]
    assert [(e["event"], e["id"]) for e in events] == [("result", 1), ("error", 2)]


def test_a_file_that_appears_while_the_view_renders_is_never_replaced(trained_run, tmp_path, monkeypatch):
    # parse_request checks that the output does not exist; the rename after rendering replaced a file
    # created meanwhile.
    target = tmp_path / "late.npy"
    real = render_view

    def render_then_someone_writes(*a, **k):
        res = real(*a, **k)
        target.write_bytes(b"the user's data")
        return res

    monkeypatch.setattr("nerf_core.render.server.render_view", render_then_someone_writes)
    events = _serve(trained_run["run"], [json.dumps(_req(1, target, depth=False))])
    assert events[1]["event"] == "error" and "appeared while the view rendered" in events[1]["message"]
    assert target.read_bytes() == b"the user's data"
    assert [p.name for p in tmp_path.iterdir()] == ["late.npy"]  # no partial file left


def test_parse_request_accepts_flat_row_major_matrices():
    req = parse_request(_req(1, "/tmp/x_never_written.npy", c2w=C2W.reshape(-1).tolist(), depth=False))
    assert np.array_equal(req["c2w"], C2W) and req["depth_out"] is None and req["near"] is None


def test_subprocess_serves_over_stdin_and_a_missing_run_is_one_fatal_line(trained_run, tmp_path):
    env = {**os.environ, "NERF_CORE_PLUGINS": "nerf_core.tests.conftest", "PYTHONPATH": str(REPO_ROOT)}
    cmd = [sys.executable, "-m", "nerf_core", "serve", str(trained_run["run"])]
    stdin = json.dumps(_req(1, tmp_path / "p.npy")) + "\n"  # end of input ends the server
    proc = subprocess.run(cmd, input=stdin, capture_output=True, text=True, env=env, timeout=120, cwd=str(REPO_ROOT))
    assert proc.returncode == 0, proc.stderr
    events = [json.loads(x) for x in proc.stdout.splitlines()]  # stdout holds JSON lines only
    assert [e["event"] for e in events] == ["ready", "result"] and np.load(tmp_path / "p.npy").shape == (18, 24, 4)

    missing = tmp_path / "no_run"
    proc = subprocess.run(cmd[:-1] + [str(missing)], input="", capture_output=True, text=True, env=env, timeout=120,
                          cwd=str(REPO_ROOT))
    assert proc.returncode == 2
    (line,) = proc.stdout.splitlines()
    ev = json.loads(line)
    assert ev["event"] == "error" and ev["fatal"] is True and str(missing) in ev["message"]
    assert "Traceback" not in proc.stderr and proc.stderr.strip() == f"nerf_core serve: error: {ev['message']}"


def test_a_final_render_request_draws_edges_through_the_runs_film_filter(trained_run, tmp_path):
    from nerf_core.image.pixel_filter import PixelFilter

    events = _serve(trained_run["run"], [json.dumps(_req(1, tmp_path / "f.npy", pixel_filter=True)),
                                         json.dumps(_req(2, tmp_path / "c.npy")),
                                         json.dumps(_req(3, tmp_path / "x.npy", pixel_filter="yes"))])
    assert [e["event"] for e in events] == ["ready", "result", "result", "error"]
    assert events[3]["message"] == "request 3: field 'pixel_filter' must be true or false, got 'yes'"
    model, config, _ = load_run(trained_run["run"], "cpu")
    cams = Cameras.create(C2W[None], 22.0, 20.0, 11.0, 8.5, 24, 18)
    kw = dict(background=(0.0, 0.0, 0.0), near=config["near"], far=config["far"])
    filtered = render_view(model, cams, 0, pixel_filter=PixelFilter(), **kw)  # the run records Blender's default
    centre = render_view(model, cams, 0, **kw)
    assert np.allclose(np.load(tmp_path / "f.npy")[..., 3], filtered["acc"].numpy(), atol=1e-6)
    assert np.allclose(np.load(tmp_path / "c.npy")[..., 3], centre["acc"].numpy(), atol=1e-6)
    assert not np.allclose(filtered["acc"].numpy(), centre["acc"].numpy(), atol=1e-3)  # the outline differs


def test_running_out_of_memory_is_one_request_error_naming_the_chunk_and_the_server_goes_on(trained_run, tmp_path,
                                                                                               monkeypatch):
    real = render_view
    calls = []

    def first_runs_out(*a, **k):
        calls.append(1)
        if len(calls) == 1:
            raise MemoryError()  # a MemoryError is no RuntimeError: it ended the server before
        return real(*a, **k)

    monkeypatch.setattr("nerf_core.render.server.render_view", first_runs_out)
    lines = [json.dumps(_req(1, tmp_path / "a.npy")), json.dumps(_req(2, tmp_path / "b.npy"))]
    events = _serve(trained_run["run"], lines, chunk=512)
    assert events[1]["event"] == "error" and events[1]["id"] == 1
    message = events[1]["message"]
    assert "serve --chunk 512: not enough memory" in message and "lower serve's --chunk" in message
    assert events[2]["event"] == "result" and events[2]["id"] == 2
    assert not (tmp_path / "a.npy").exists()
