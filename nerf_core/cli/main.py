"""``python -m nerf_core``: train, render, eval, check, export, score-mesh (and list methods).

Stable flags are documented in docs/CONTRACTS.md. Expected problems (bad dataset, existing run,
missing checkpoint) end with one ``nerf_core <command>: error: ...`` line on stderr and exit code 2,
never a traceback. Set ``NERF_CORE_PLUGINS=module.a,module.b`` to import modules that register
extra methods before a command runs.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import signal
import sys
from typing import List, Optional

from nerf_core.cli import check, evaluate, export, render, score_mesh, serve, train
from nerf_core.cli.options import HelpFormatter
from nerf_core.contract.errors import DatasetError
from nerf_core.errors import ImageReadError, RunError, TrainError
from nerf_core.methods import catalog
from nerf_core.methods.registry import available_methods, method_class
from nerf_core.runs.folder import os_error_text
from nerf_core.utils.interrupts import honour_interrupts
from nerf_core.utils.stdout import NamedStdout, StdoutClosed

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def _load_plugins() -> None:
    for name in filter(None, (s.strip() for s in os.environ.get("NERF_CORE_PLUGINS", "").split(","))):
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise ValueError(f"NERF_CORE_PLUGINS: cannot import {name!r} ({exc})") from exc


def build_parser() -> argparse.ArgumentParser:
    fmt = HelpFormatter
    p = argparse.ArgumentParser(
        prog="python -m nerf_core",
        description="Train NeRFs on Blender (or any NeRF-synthetic / nerfstudio) datasets, render novel views, "
                    "evaluate and validate datasets. CPU first; CUDA when available.",
        epilog="examples:\n"
               "  python -m nerf_core check scene_dataset\n"
               "  python -m nerf_core train scene_dataset --out runs/scene --max-seconds 600\n"
               "  python -m nerf_core eval runs/scene --split test\n"
               "  python -m nerf_core render runs/scene --cameras scene_dataset/transforms_test.json --out renders",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    for command in (train, render, evaluate, check, serve, export, score_mesh):
        command.add_parser(sub, fmt)
    m = sub.add_parser("methods", help="list the available methods, or one method's options", formatter_class=fmt)
    m.add_argument("name", nargs="?", metavar="METHOD", help="list this method's options (train --set KEY=VALUE)")
    m.set_defaults(handler=_cmd_methods)
    return p


def _cmd_methods(a) -> int:
    if a.name is None:
        for name in available_methods():
            print(name + ("  (default)" if name == catalog.DEFAULT_METHOD else ""))
        return 0
    cls = method_class(a.name)
    if cls is None:
        raise ValueError(f"unknown method {a.name!r}; choose one of {', '.join(available_methods())}")
    defaults, docs, allowed = cls.parse_options({}).to_dict(), cls.Options.docs(), cls.Options.allowed()
    if not docs:
        print(f"{a.name}: declares no options")
    for key, doc in docs.items():
        fixed = " (fixed)" if key in cls.forced_options else ""
        print(f"{key} = {json.dumps(defaults[key])}{fixed}\n    {doc}" + ("" if fixed else f" ({allowed[key]})"))
    return 0




def main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    expected = (DatasetError, RunError, TrainError, ImageReadError, ValueError, OSError)
    honour_interrupts()  # a Cancel (SIGINT/SIGTERM) must stop us cleanly, whatever the parent ignored
    if hasattr(signal, "SIGXFSZ"):  # past ``ulimit -f`` a write raises EFBIG, named, instead of killing us
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    plain_stdout, sys.stdout = sys.stdout, NamedStdout(sys.stdout)  # a full or closed stdout is named
    try:
        _load_plugins()
        code = args.handler(args)
        sys.stdout.flush()  # > /dev/full fails here, named, rather than at exit unnamed
        return code
    except StdoutClosed as exc:
        print(f"nerf_core {args.command}: interrupted: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except expected as exc:
        msg = str(exc) or type(exc).__name__
        if isinstance(exc, OSError) and msg.startswith("[Errno"):  # a bare OSError, not one of our messages
            msg = os_error_text(exc)
        print(f"nerf_core {args.command}: error: {msg}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"nerf_core {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        sys.stdout = plain_stdout
