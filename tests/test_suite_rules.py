"""The suite's own rules (``tests/conftest.py``): a skip fails the run, and no test waits on the clock."""

import os
import re
import subprocess
import sys

from tests.conftest import ALLOWED_SKIPS, ROOT


def test_a_skipped_test_or_module_fails_the_run(tmp_path):
    (tmp_path / "test_missing.py").write_text(
        "import pytest\n"
        "pytest.importorskip('colorgrid_no_such_dependency')\n"
        "def test_never_collected():\n"
        "    pass\n")
    (tmp_path / "test_skips.py").write_text(
        "import pytest\n"
        "def test_passes():\n"
        "    assert True\n"
        "def test_skips():\n"
        "    pytest.skip('not today')\n")
    def run(name: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "pytest", "-p", "tests.conftest", "-p", "no:cacheprovider",
                               "--rootdir", str(tmp_path), "-c", "/dev/null", "-q", str(tmp_path / name)],
                              capture_output=True, text=True, cwd=ROOT, timeout=300)

    missing = run("test_missing.py")  # an error at collection, as an import that fails
    assert missing.returncode == 2 and "1 error" in missing.stdout, missing.stdout + missing.stderr
    assert "could not import 'colorgrid_no_such_dependency'" in missing.stdout
    skipped = run("test_skips.py")
    assert skipped.returncode == 1 and re.search(r"\b1 failed, 1 passed\b", skipped.stdout), skipped.stdout
    assert "skipped (not today); a skip fails the run" in skipped.stdout
    assert ALLOWED_SKIPS == {}, "no test is meant to skip today; list one with the reason it may"


def test_no_test_waits_a_fixed_time_or_asserts_one():
    """A wait stands for an event (``expect``, ``wait_for_function``, a message), never for a duration; and what a
    test asserts is counts and events, not how long something took."""
    banned = re.compile("wait_for_" + "timeout|elapsed" + " <")  # spelt apart, so as not to find this line
    found = [f"{path.name}:{n}: {line.strip()}" for path in sorted((ROOT / "tests").glob("*.py"))
             for n, line in enumerate(path.read_text().splitlines(), 1) if banned.search(line)]
    assert found == []


def test_every_file_that_starts_a_ray_runs_on_the_ray_worker():
    """`make test` runs several workers (tests/scheduling.py); a file that starts a Ray beside another would give each
    Ray the machine's CPUs: every such file is in RAY_FILES, and every file there exists."""
    from tests.scheduling import RAY_FILES

    starts_ray = re.compile(r"^\s*(import|from) ray\b|\bray\.init\(|\"--head\"|\bray_instance\b", re.M)
    found = {f"tests/{path.name}" for path in (ROOT / "tests").glob("test_*.py") if starts_ray.search(path.read_text())}
    assert found == set(RAY_FILES)


def test_the_longest_units_named_for_the_workers_exist():
    """A renamed or removed file left in LONGEST_FIRST, or a Ray file (whose unit is the Ray unit), would no longer be
    handed out first, silently."""
    from tests.scheduling import LONGEST_FIRST, RAY_FILES

    assert LONGEST_FIRST[0] == "ray" and len(set(LONGEST_FIRST)) == len(LONGEST_FIRST)
    assert not set(LONGEST_FIRST) & RAY_FILES
    missing = [name for name in LONGEST_FIRST[1:] if not (ROOT / name).is_file()]
    assert missing == []


def test_torch_threads_wait_without_spinning_in_every_process_the_tests_start(request):
    """``OMP_WAIT_POLICY`` only counts if it is set before torch's OpenMP runtime starts: conftest sets it (passive,
    unless the caller chose) before this worker imported torch, and a subprocess a test starts inherits it."""
    conftest = request.config.pluginmanager.get_plugin(str(ROOT / "tests" / "conftest.py"))  # the copy pytest loaded
    assert conftest.TORCH_LOADED_BEFORE is False
    assert conftest.OMP_WAIT_POLICY == "PASSIVE" and os.environ.get("OMP_WAIT_POLICY")
    child = subprocess.run([sys.executable, "-c", "import os; print(os.environ.get('OMP_WAIT_POLICY'))"],
                           capture_output=True, text=True, timeout=60)
    assert child.stdout.strip() == os.environ["OMP_WAIT_POLICY"], child.stderr
