"""``python -m nerf_core check DATASET``: every problem of a dataset, before training.
"""
from __future__ import annotations

import json

from nerf_core.check.dataset import check_dataset
from nerf_core.data.backgrounds import BACKGROUNDS


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    c = sub.add_parser(
        "check",
        help="validate a dataset folder against the dataset conventions",
        formatter_class=fmt,
        description="Exit 0 when valid; otherwise exit 1 and list every problem with its file/frame/field.",
    )
    c.add_argument("dataset", metavar="DATASET", help="dataset folder")
    c.add_argument("--json", action="store_true", help="print the report as one JSON object")
    c.add_argument("--for-training", action="store_true",
                   help="errors are only what `train` refuses; the conventions an export keeps for other tools' "
                        "loaders become warnings (a dataset of another tool trains)")
    c.add_argument("--background", default="auto", choices=list(BACKGROUNDS),
                   help="the train --background to check the images against (warns when opaque images meet a mode "
                        "that cannot show their background)")
    c.set_defaults(handler=run)


def run(a) -> int:
    report = check_dataset(a.dataset, background=a.background, for_training=a.for_training)
    if a.json:
        print(json.dumps(report.as_dict()))
    else:
        print(report.format())
    return 0 if report.ok else 1
