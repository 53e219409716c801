"""The wheel's allow-list (scripts/check_wheel.py, run by make wheel-check): library and CLI only."""

import ast
import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("check_wheel", ROOT / "scripts" / "check_wheel.py")
cw = importlib.util.module_from_spec(spec)
sys.modules["check_wheel"] = cw
spec.loader.exec_module(cw)

GOOD = ["isplat/__init__.py", "isplat/cli/main.py", "isplat/renderer.py", "isplat/index/store.py",
        "isplat-0.1.0.dist-info/METADATA", "isplat-0.1.0.dist-info/entry_points.txt"]


def test_library_and_cli_pass():
    assert cw.offenders(GOOD) == []


def test_benchmarks_tests_and_strays_are_named():
    strays = ["benchmarks/paper.py", "isplat/bench/paper.py", "tests/conftest.py", "conftest.py", "data/x.npy"]
    assert cw.offenders(GOOD + strays) == strays


def test_prebuilt_kernels_once_made_must_be_shipped():
    assert cw.offenders(GOOD, prebuilt=True) == ["missing: isplat/_prebuilt/manifest.json"]
    assert cw.offenders(GOOD + ["isplat/_prebuilt/manifest.json"], prebuilt=True) == []
    assert cw.offenders(GOOD + ["isplat/_prebuilt/manifest.json"]) == ["isplat/_prebuilt/manifest.json"]


def test_a_missing_cli_is_named():
    assert cw.offenders([n for n in GOOD if n != "isplat/cli/main.py"]) == ["missing: isplat/cli/main.py"]


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    return {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names} | \
           {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}


def test_imported_modules_sees_nested_imports(tmp_path):
    (tmp_path / "t.py").write_text("import os\ndef f():\n    from benchmarks.paper import decimate\n")
    assert imported_modules(tmp_path / "t.py") == {"os", "benchmarks.paper"}


def test_tests_do_not_import_the_benchmarks():
    for path in [*(ROOT / "tests").glob("*.py"), *ROOT.glob("conftest.py")]:
        bench = {m for m in imported_modules(path) if m.split(".")[0] == "benchmarks" or m.startswith("isplat.bench")}
        assert not bench, (path.name, bench)


def test_the_command_line_runs_without_the_editable_installs_imports():
    """An installed wheel has no editable-install finder, which imports importlib.util as a side effect: the
    command line must import what it uses itself (it failed with AttributeError: module 'importlib' has no
    attribute 'util'). Here without site (-S): isplat and the libraries from PYTHONPATH only."""
    import os
    import site
    import subprocess

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *site.getsitepackages()]))
    out = subprocess.run([sys.executable, "-S", "-m", "isplat", "render", "--help"], env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "Usage: isplat render" in out.stdout
