"""`python -m asbuilt ARGS...`: the `asbuilt` command line, from the installed package."""

import sys

from . import run

if __name__ == "__main__":
    sys.exit(run(*sys.argv[1:]))
