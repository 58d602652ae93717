"""How `make test` shares the tests between its two workers (pytest-xdist): by file, with the files that start a Ray
as one unit, so that two Rays never run at once (each takes the machine's CPUs and a share of its memory).

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


class FileScheduling(LoadScopeScheduling):
    """Each test file one unit of work, and the Ray files together one unit, handed out first: it is the longest
    (about half the suite's wall time on a 2-core machine), so the other worker runs the rest beside it rather than
    after it."""

    def _split_scope(self, nodeid: str) -> str:
        path = nodeid.split("::", 1)[0]
        return "ray" if path in RAY_FILES else path

    def _assign_work_unit(self, node) -> None:
        if "ray" in self.workqueue:
            self.workqueue.move_to_end("ray", last=False)
        super()._assign_work_unit(node)
