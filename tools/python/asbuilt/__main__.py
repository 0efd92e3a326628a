"""`python -m asbuilt ARGS...`: the `asbuilt` command line, from the installed package;
`python -m asbuilt archive ...` inspects a fleet's recordings on Dask (the `archive` extra)."""

import sys

from . import run

if __name__ == "__main__":
    if sys.argv[1:2] == ["archive"]:
        try:
            from .archive import main
        except ImportError as e:
            sys.exit(f"python -m asbuilt archive needs the archive extra ({e.name} is missing): "
                     'pip install "./tools/python[archive]"')
        sys.exit(main(sys.argv[2:]))
    sys.exit(run(*sys.argv[1:]))
