"""Build isplat's wheel and check that it holds the library and the CLI only (make wheel-check).

Every file must sit under ``isplat/`` or the wheel's ``.dist-info/``, none may come from the benchmarks or the
tests, and the CLI's entry module must be there, and the prebuilt kernels when they were made (make prebuilt). Prints the count on success; on failure, the offending names
and exit status 1.
"""

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
    required = REQUIRED + ((PREBUILT,) if prebuilt else ())
    return bad + [f"missing: {r}" for r in required if r not in names]


def build(out: Path) -> Path:
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "-w", str(out), "--no-deps", "-q"],
                   check=True)
    return next(out.glob("isplat-*.whl"))


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="isplat-wheel-") as tmp:
        wheel = build(Path(tmp))
        names = zipfile.ZipFile(wheel).namelist()
    bad = offenders(names, prebuilt=(ROOT / PREBUILT).exists())
    for n in bad:
        print(f"check_wheel: {wheel.name}: {n}", file=sys.stderr)
    if not bad:
        print(f"check_wheel: {wheel.name}: {len(names)} files, all under isplat/ or its .dist-info/")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
