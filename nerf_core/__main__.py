"""``python -m nerf_core COMMAND ...``; see ``nerf_core.cli.main``."""
import sys

from nerf_core.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
