"""How `make test` shares the tests between its workers (pytest-xdist; the Makefile's ``TEST_WORKERS`` says how many):
by file, with the files that start a Ray as one unit, so that two Rays never run at once (each takes the machine's
CPUs and a share of its memory), and the longest units handed out first, so that long files start early rather than
last (xdist gives a worker its next unit while two of its tests are still to run, so the order cannot promise more).

xdist's own ``--dist loadgroup`` would do the second part from ``xdist_group`` marks, but it renames each test's node
id to carry its group, which pytest 9.2 no longer allows (the node id is derived, not stored): the marks are ignored
and a group's tests spread over both workers. Splitting by file is xdist's documented way in (``_split_scope``)."""

from __future__ import annotations

from xdist.scheduler import LoadScopeScheduling

RAY_FILES = frozenset({
    "tests/test_examples.py",  # RLlib's multi-agent PPO
    "tests/test_ray_start_cluster.py",
    "tests/test_rllib_flat.py",
    "tests/test_sweep.py",
    "tests/test_sweep_cluster.py",
})
"""The test files that start a Ray (in the test process or as a ``ray start`` cluster): one unit of work."""


LONGEST_FIRST = (
    "ray",
    "tests/test_train.py",
    "tests/test_sweep_local.py",
    "tests/test_wheel.py",
    "tests/test_page_connections.py",
    "tests/test_benchmarl.py",
    "tests/test_server_hardening.py",
    "tests/test_viewer.py",
    "tests/test_cluster_failover.py",
    "tests/test_study_power.py",
    "tests/test_browser.py",
    "tests/test_study.py",
)
"""The units that took longest (the sum of their tests' setup, call and teardown in run 41,
``PYTEST_ADDOPTS=--durations=0``, docs/PERFORMANCE.md), longest first: handed out before every other unit (which
follow in xdist's order, most tests first). The order changes only when each file runs, never what it finds: each
file starts what it needs."""


class FileScheduling(LoadScopeScheduling):
    """Each test file one unit of work, and the Ray files together one unit; ``LONGEST_FIRST`` handed out first
    (the Ray unit is the longest, so the other workers run the rest beside it rather than after it)."""

    def _split_scope(self, nodeid: str) -> str:
        path = nodeid.split("::", 1)[0]
        return "ray" if path in RAY_FILES else path

    def _assign_work_unit(self, node) -> None:
        for scope in reversed(LONGEST_FIRST):
            if scope in self.workqueue:
                self.workqueue.move_to_end(scope, last=False)
        super()._assign_work_unit(node)
