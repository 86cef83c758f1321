"""``python -m nerf_core train DATASET --out RUN``: its flags, and the run they start.
"""
from __future__ import annotations

from nerf_core.cli.options import (
    folder,
    nonneg_int,
    parse_options,
    positive_float,
    positive_int,
    seconds_list,
)
from nerf_core.data.backgrounds import BACKGROUNDS
from nerf_core.engine.config import TrainConfig
from nerf_core.engine.trainer import train
from nerf_core.errors import TrainError
from nerf_core.methods.registry import current_option_names


def add_parser(sub, fmt) -> None:
    """Add the subcommand to ``sub`` (argparse subparsers); ``fmt``: the help formatter class."""
    t = sub.add_parser("train", help="train a method on a dataset into a run folder", formatter_class=fmt,
                       description="Train a NeRF. JSON progress events go to stdout and RUN/progress.jsonl; "
                                   "a progress bar with ETA goes to stderr.")
    t.add_argument("dataset", metavar="DATASET", help="dataset folder (transforms_train.json or transforms.json) or a transforms file")
    t.add_argument("--out", required=True, type=folder, metavar="RUN", help="run folder to create (refused if it exists and is not empty)")
    t.add_argument("--method", metavar="M", help="method name (see `python -m nerf_core methods`); default: the library's default method")
    t.add_argument("--max-steps", type=positive_int, metavar="N", help="stop after N optimisation steps")
    t.add_argument("--max-seconds", type=positive_float, metavar="S",
                   help="stop after S seconds of training (previews, checkpoints and evaluation not counted)")
    t.add_argument("--seed", type=int, default=0, metavar="K", help="random seed (same seed + step budget = the same losses on a CPU; on CUDA equal to about "
                        "1e-7, since its atomic adds sum gradients in no fixed order)")
    t.add_argument("--resume", action="store_true",
                   help="continue RUN from RUN/checkpoints/latest.pt (else its newest step_*.pt); DATASET must hold "
                        "the dataset the run was trained on (checked by the hash of its transforms files)")
    t.add_argument("--dataset-moved", action="store_true",
                   help="with --resume: accept a DATASET path other than the recorded one for a run that recorded "
                        "no dataset hash (newer runs accept a moved dataset by its hash without this flag)")
    t.add_argument("--overwrite", action="store_true", help="start RUN again, deleting only files an earlier training wrote")
    t.add_argument("--size", choices=["auto"], help="let nerf_core.methods.sizing choose the model size for this dataset")
    t.add_argument("--unbounded", "--contract", dest="unbounded", action="store_true",  # --contract: its old name
                   help="scene contraction (mip-NeRF 360 style): also model geometry beyond the scene box, such as a "
                        "ground plane running to the horizon (vmgrid; the same as --set unbounded=true). Without it, "
                        "a cut-out whose opaque pixels look past the box gets it anyway; --set unbounded=false stops that")
    t.add_argument("--progress", metavar="FILE", help="also append the JSON progress events to FILE")
    t.add_argument("--device", metavar="DEV", help="torch device (cpu, cuda, cuda:1); default: cuda if available else cpu")
    t.add_argument("--lr", type=positive_float, help="base learning rate (default: the method's)")
    t.add_argument("--batch-rays", type=positive_int, metavar="N",
                   help="rays per step (default: the method's, 1024 for a method without one; 4x that on CUDA)")
    t.add_argument("--background", choices=list(BACKGROUNDS), default="auto",
                   help="what stands behind the scene while training: environment = a learned world (light from "
                        "infinity, for opaque captures); random = a random colour per ray behind the alpha (cut-outs "
                        "on a transparent film); white-then-random = white for the first 20%% of the budget, then "
                        "random. auto picks environment or random from the dataset's film_transparent and the "
                        "images' alpha, and says why")
    t.add_argument("--downscale", type=positive_int, default=1, metavar="F", help="train on images downscaled by F")
    t.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="options",
                   help="method option, repeatable (e.g. --set n_samples=64)")
    t.add_argument("--log-every", type=positive_int, default=50, metavar="N", help="emit a step event every N steps")
    t.add_argument("--preview-every", type=positive_int, metavar="N", help="preview every N steps (default: every 30 s of training)")
    t.add_argument("--checkpoint-every", type=positive_int, metavar="N", help="checkpoint every N steps (default: every 5 min)")
    t.add_argument("--eval-views", type=nonneg_int, metavar="N",
                   help="held-out views to evaluate at the end (0 = none; default: as many as fit in 25%% of the training time)")
    t.add_argument("--eval-at", metavar="S1,S2,...", type=seconds_list, default=[],
                   help="also evaluate held-out views at these training times (seconds), e.g. 60,120,300")
    t.add_argument("--no-bar", action="store_true", help="no progress bar on stderr")
    t.set_defaults(handler=run)


def run(a) -> int:
    cfg = TrainConfig(
        dataset=a.dataset, out=a.out, method=a.method, max_steps=a.max_steps, max_seconds=a.max_seconds, seed=a.seed,
        resume=a.resume, overwrite=a.overwrite, dataset_moved=a.dataset_moved, size=a.size,
        options=_options(a), progress=a.progress,
        device=a.device, lr=a.lr, batch_rays=a.batch_rays, background=a.background, downscale=a.downscale,
        log_every=a.log_every, preview_every=a.preview_every, checkpoint_every=a.checkpoint_every,
        eval_views=a.eval_views, eval_at=a.eval_at, show_bar=not a.no_bar,
    )
    train(cfg)
    return 0


def _options(a) -> dict:
    """``--set`` options (old option names mapped to today's), with ``--unbounded`` as ``unbounded=true``;
    the two flags must not disagree."""
    try:
        options = current_option_names(parse_options(a.options))
    except ValueError as exc:
        raise TrainError(f"--set: {exc}") from None
    if a.unbounded:
        if options.get("unbounded", True) is not True:
            raise TrainError(f"--unbounded and --set unbounded={options['unbounded']} disagree; give one of them")
        options["unbounded"] = True
    return options
