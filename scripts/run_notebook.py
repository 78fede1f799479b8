"""Execute a notebook top to bottom and write the executed copy.

    python scripts/run_notebook.py notebooks/specularity_sharpness.ipynb OUT.ipynb [--full]

``--full`` sets SHINYSIM_FULL=1 (the notebooks' full settings). The stored
notebook is never modified; OUT must not exist.
"""

import argparse
import os
import sys
from pathlib import Path

import nbclient
import nbformat


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("notebook")
    p.add_argument("out")
    p.add_argument("--full", action="store_true", help="the notebook's full settings (SHINYSIM_FULL=1)")
    args = p.parse_args()
    out = Path(args.out)
    if out.exists():
        sys.exit(f"{out} exists; not overwriting it")
    if args.full:
        os.environ["SHINYSIM_FULL"] = "1"
    nb = nbformat.read(args.notebook, as_version=4)
    nbclient.NotebookClient(nb, timeout=None, kernel_name="python3",
                            resources={"metadata": {"path": str(Path(args.notebook).parent)}}).execute()
    nbformat.write(nb, out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
