"""Benchmarks behind `make bench` and `make paper-table`, run from the repository root:
``python -m benchmarks NAME|all [--out docs] [--quick]``. Not part of the installed package (the wheel holds
only ``isplat``), and the tests do not import it.

Each module NAME has ``run(out_dir: Path, quick: bool) -> Path`` that measures, writes one Markdown file under
``out_dir`` (docs/ by default) starting with the command that made it, and returns its path; and declares
``TECHNIQUES`` (the ``render.classification`` of its rows: "pre", "post", both or none), ``SOURCES`` (the git
globs whose change makes its page stale) and, when it writes one section of a shared page, ``SECTION``. After
``run`` the page or section gets its stamp (``_doc.stamp_output``; a module with ``STAMPS_ITSELF`` stamps it
itself), which ``make docs-check`` reads. Timings are medians
of several runs; ratios are measured side by side in one run."""
