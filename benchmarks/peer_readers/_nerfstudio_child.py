"""Runs under an interpreter with nerfstudio: ``PY _nerfstudio_child.py COLMAP_DIR OUT_JSON``.

Reads COLMAP_DIR with nerfstudio's ``colmap`` dataparser and writes what it returned for the train
split as JSON (plain lists and numbers, so the comparison runs in the project's own Python). Imports
nothing of this project: nerfstudio's environment need not have it.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path


def main(argv) -> int:
    data, out = Path(argv[0]), Path(argv[1])
    import nerfstudio
    from nerfstudio.data.dataparsers.colmap_dataparser import ColmapDataParserConfig

    options = dict(colmap_path=Path("sparse/0"), images_path=Path("images"),
                   masks_path=Path("masks") if (data / "masks").is_dir() else None,
                   load_3D_points=True, eval_mode="all", downscale_factor=1)
    config = ColmapDataParserConfig(data=data, **options)
    outputs = config.setup().get_dataparser_outputs(split="train")  # its public call
    cams = outputs.cameras
    n = len(outputs.image_filenames)

    def column(t):
        return [float(v) for v in t.reshape(-1).tolist()]

    points = outputs.metadata.get("points3D_xyz")
    result = {
        "nerfstudio_version": getattr(nerfstudio, "__version__", None) or _version("nerfstudio"),
        "torch_version": _version("torch"),
        "options": {k: (str(v) if isinstance(v, Path) else v) for k, v in options.items()},
        "num_images": n,
        "image_filenames": [Path(p).name for p in outputs.image_filenames],
        "mask_filenames": [str(p) for p in outputs.mask_filenames] if outputs.mask_filenames else None,
        "fx": column(cams.fx), "fy": column(cams.fy), "cx": column(cams.cx), "cy": column(cams.cy),
        "width": [int(v) for v in cams.width.reshape(-1).tolist()],
        "height": [int(v) for v in cams.height.reshape(-1).tolist()],
        "camera_type": [int(v) for v in cams.camera_type.reshape(-1).tolist()],
        "camera_to_worlds": cams.camera_to_worlds.double().tolist(),
        "dataparser_transform": outputs.dataparser_transform.double().tolist(),
        "dataparser_scale": float(outputs.dataparser_scale),
        "num_points3D": None if points is None else int(points.shape[0]),
    }
    # a new file, never through a link (the project's atomic writer is not importable here: this runs
    # under nerfstudio's interpreter, which imports nothing of ours); the caller gives a fresh folder
    fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o644)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(json.dumps(result, indent=1))
    return 0


def _version(dist: str):
    try:
        from importlib.metadata import version

        return version(dist)
    except Exception:  # noqa: BLE001  (a version is a note, not a requirement)
        return None


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
