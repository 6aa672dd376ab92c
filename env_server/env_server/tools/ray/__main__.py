"""`python -m env_server.tools.ray`: the Ray launcher's entry point (the code is in launcher.py)."""

import sys

from env_server.tools.ray.launcher import main

if __name__ == "__main__":
    sys.exit(main())
