"""Build isplat's wheel and check that it holds the library and the CLI only (make wheel-check).

Every file must sit under ``isplat/`` or the wheel's ``.dist-info/``, none may come from the benchmarks or the
tests, and the CLI's entry module must be there; with the prebuilt kernels (make prebuilt) the wheel must hold
them and be tagged for the platform (setup.py), without them it must be pure Python. Prints the count on success; on failure, the offending names
and exit status 1.
"""

import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REQUIRED = ("isplat/__init__.py", "isplat/cli/main.py", "isplat/renderer.py")
PREBUILT = "isplat/_prebuilt/manifest.json"       # the prebuilt kernels (make prebuilt), shipped when made


def offenders(names: list[str], prebuilt: bool = False) -> list[str]:
    """Names of a wheel that do not belong there, plus any required file that is missing (with ``prebuilt``,
    the prebuilt kernels' manifest too)."""
    bad = [n for n in names if not (n.startswith("isplat/") or n.split("/")[0].endswith(".dist-info"))
           or "/bench" in n or n.startswith("isplat/tests")]
    if not prebuilt:
        bad += [n for n in names if n.startswith("isplat/_prebuilt/")]
    required = REQUIRED + ((PREBUILT,) if prebuilt else ())
    return bad + [f"missing: {r}" for r in required if r not in names]


def build(out: Path) -> Path:
    """The wheel, built afresh: setuptools' build/ folder keeps copies of earlier builds' files (prebuilt
    kernels since removed would be shipped again), so it goes first."""
    shutil.rmtree(ROOT / "build", ignore_errors=True)
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "-w", str(out), "--no-deps", "-q"],
                   check=True)
    return next(out.glob("isplat-*.whl"))


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="isplat-wheel-") as tmp:
        wheel = build(Path(tmp))
        names = zipfile.ZipFile(wheel).namelist()
    prebuilt = (ROOT / PREBUILT).exists()
    bad = offenders(names, prebuilt=prebuilt)
    if prebuilt == wheel.name.endswith("-py3-none-any.whl"):
        bad.append(f"tagged {'pure Python' if prebuilt else 'for a platform'}: the prebuilt kernels (machine code) "
                   f"are {'in' if prebuilt else 'not in'} it")
    for n in bad:
        print(f"check_wheel: {wheel.name}: {n}", file=sys.stderr)
    if not bad:
        print(f"check_wheel: {wheel.name}: {len(names)} files, all under isplat/ or its .dist-info/")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
