"""``python -m nerf_core COMMAND ...``; see ``nerf_core.cli``."""
import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
