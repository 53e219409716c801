"""Benchmarks behind `make bench` and `make paper-table`, run from the repository root:
``python -m benchmarks NAME|all [--out docs] [--quick]``. Not part of the installed package (the wheel holds
only ``isplat``), and the tests do not import it.

Each module NAME has ``run(out_dir: Path, quick: bool) -> Path`` that measures, writes one Markdown file under
``out_dir`` (docs/ by default) starting with the command that made it, and returns its path. Timings are medians
of several runs; ratios are measured side by side in one run."""
