"""The ``jaxanom`` command line (filled in by the data/CLI issue)."""
from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="jaxanom", description=__doc__)
    parser.parse_args(argv)
    return 0
