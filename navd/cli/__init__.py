"""Command-line entry points: argparse and ``main`` only; the work lives in the library."""
