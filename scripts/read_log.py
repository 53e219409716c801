"""Every read HDF5 makes while a scene's first view loads and renders, summed per file and per dataset (a
developer's tool for issue 26's read / needed; docs/design.md, "Positions as nested masks").

    .venv/bin/python scripts/read_log.py SCENE.toml [--reads]
    .venv/bin/python scripts/read_log.py --case E2 [--reads]

``--case NAME``: instead of a scene, the selective-read benchmark's case NAME (H1, E2, B1, H1-512, C1: its volume
augmented, ``isplat index`` of it and its post scene, as ``python -m benchmarks selective_read`` makes them, in a
temporary folder).

The scene's files are opened as ``isplat render`` opens them (``isplat.renderer.Renderer``, one pass); each read of
the counted file objects (``isplat.fileio``'s, the ones the report's bytes come from) is logged with its file
offset and size, then attributed to the dataset whose chunk (or contiguous storage) holds its first byte, else to
``meta`` (object headers, chunk indexes, attributes). Prints the report's read and needed bytes, then per file
its bytes and per dataset its bytes and reads; ``--reads`` also every read (file, offset, size).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def storage_map(path) -> list[tuple[int, int, str]]:
    """(offset, size, dataset) of every chunk (or contiguous storage) of the file's datasets, by offset."""
    import h5py

    spans = []
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if not isinstance(obj, h5py.Dataset):
                return
            if obj.chunks:
                for n in range(obj.id.get_num_chunks()):
                    info = obj.id.get_chunk_info(n)
                    spans.append((info.byte_offset, info.size, name))
            elif obj.id.get_offset() is not None:
                spans.append((obj.id.get_offset(), obj.id.get_storage_size(), name))
        f.visititems(visit)
    return sorted(spans)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/read_log.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path, nargs="?")
    ap.add_argument("--case", help="a case of benchmarks/selective_read.py instead of a scene")
    ap.add_argument("--reads", action="store_true", help="also print every read")
    a = ap.parse_args(argv)
    if (a.scene is None) == (a.case is None):
        ap.error("give a scene or --case NAME")
    if a.case:
        import tempfile

        from benchmarks.selective_read import _index, _scene, cases

        with tempfile.TemporaryDirectory(prefix="isplat-readlog-") as t:
            c = cases(Path(t), False, only=[a.case])[0]
            idx = Path(t) / f"{a.case}.idx.h5"
            _index(c["aug"], idx, False)
            return log_scene(_scene(Path(t), c, idx, "post"), a.reads)
    return log_scene(a.scene, a.reads)


def log_scene(scene_path: Path, reads: bool) -> int:
    """Render the scene's first view with every read logged; print the sums (and ``reads``: every read)."""
    from isplat import fileio
    from isplat.renderer import Renderer
    from isplat.scene import load_scene

    log = []
    readinto = fileio._CountingRaw.readinto

    def logged(self, buf):
        at = self._f.tell()
        n = readinto(self, buf)
        log.append((self._f.name, at, n or 0))
        return n

    fileio._CountingRaw.readinto = logged
    scene = load_scene(scene_path)
    r = Renderer(scene, (scene.views[0],), slabs=1)
    r.render_view(0)
    rep = r.report
    print(f"read {rep.file_bytes:,} B, needed {rep.bytes_needed:,} B, read / needed {rep.read_ratio:.4f} "
          f"({rep.technique}, values from {rep.values_from})")
    by, count, maps = collections.defaultdict(collections.Counter), collections.defaultdict(collections.Counter), {}
    for path, at, n in log:
        spans = maps.setdefault(path, storage_map(path))
        i = bisect.bisect_right([s[0] for s in spans], at) - 1
        name = spans[i][2] if i >= 0 and at < spans[i][0] + spans[i][1] else "meta"
        by[path][name] += n
        count[path][name] += 1
    for path in by:
        print(f"{path}: {sum(by[path].values()):,} B")
        for name, n in by[path].most_common():
            print(f"   {name:44s} {n:11,} B in {count[path][name]} reads")
    if reads:
        for path, at, n in log:
            print(Path(path).name, at, n)
    return 0


if __name__ == "__main__":
    sys.exit(main())
