"""A study on three backends behind HAProxy sharing one PostgreSQL database (a real cluster, ``tests/pg.py``):
200 participants arriving at once are assigned under the database's lock (quotas exact, balanced, nobody
twice), each participant's requests all reach one backend, and the proxy's ``/api/health`` and the admin page
report every backend."""

from __future__ import annotations

import asyncio
import json
import tomllib
from collections import Counter

import httpx
import pytest

from server.cluster.haproxy import BACKEND_HEADER, ROUTE_COOKIE
from server.study.config import load_study
from server.study.service import study_hash
from server.study.store import StudyStore
from tests.test_cluster import socket_to, start_cluster, stop_cluster
from tests.test_study import TOKEN, fast_study, toml

QUOTA = 45
"""Per arm (four orders): 180 places for 200 people."""


@pytest.fixture(scope="module")
def study_cluster(tmp_path_factory, postgres):
    tmp = tmp_path_factory.mktemp("pg-cluster")
    data = tomllib.loads(fast_study(tmp).read_text())
    data["max_participants"] = 1000
    data["design"]["quota"] = QUOTA
    path = tmp / "study.toml"
    path.write_text(toml(data))
    database = postgres.new_database()
    cluster = start_cluster(tmp, "--database", database, command=("study", "run", str(path)), processes=3,
                            env={"COLORGRID_ADMIN_TOKEN": TOKEN})
    cluster.study, cluster.database = load_study(path), database
    yield cluster
    stop_cluster(cluster)


async def arrive(client: httpx.AsyncClient, pid: str) -> tuple[str, str, str]:
    """A participant opening the study link, then joining as the page does (with the page's cookie): the backend
    of each request and how the join ended."""
    page = await client.get(f"/study?PROLIFIC_PID={pid}")
    cookie = {"Cookie": f"{ROUTE_COOKIE}={page.cookies[ROUTE_COOKIE]}"}
    join = await client.post("/api/study/join", json={"params": {"PROLIFIC_PID": pid}}, headers=cookie)
    detail = join.json().get("detail", "")
    ended = "joined" if join.status_code == 200 else "full" if "full" in detail else "already started"
    return page.headers[BACKEND_HEADER], join.headers[BACKEND_HEADER], ended


async def everyone_at_once(url: str, pids: list[str]) -> list[tuple[str, str, str]]:
    limits = httpx.Limits(max_connections=400, max_keepalive_connections=0)
    async with httpx.AsyncClient(base_url=url, timeout=120, limits=limits) as client:
        return await asyncio.gather(*(arrive(client, pid) for pid in pids))


def test_200_participants_at_once_over_three_backends_keep_quotas_exact_and_balance(study_cluster):
    pids = [f"p{i}" for i in range(200)]
    arrivals = [pid for pair in zip(pids, reversed(pids)) for pid in pair]  # each twice: the second is refused
    results = asyncio.run(everyone_at_once(study_cluster.url, arrivals))
    assert Counter(ended for _, _, ended in results) == {"joined": 180, "already started": 180, "full": 40}
    backends = {}
    for pid, (page, join, _) in zip(arrivals, results):
        assert page == join, pid  # the page and its API call reach one backend...
        assert backends.setdefault(pid, page) == page, pid  # ...and so does the same id arriving again
    spread = Counter(backends.values())
    assert set(spread) == {"b1", "b2", "b3"} and min(spread.values()) >= 30, spread  # every backend took its share

    study = study_cluster.study
    store = StudyStore(study_cluster.database, study.id, study_hash(study))
    try:
        rows = store.participants()
    finally:
        store.close()
    assert len(rows) == len({r["pid"] for r in rows}) == 180
    assert Counter(r["arm"] for r in rows) == {0: QUOTA, 1: QUOTA, 2: QUOTA, 3: QUOTA}
    summary = study_cluster.request("/api/study/admin/summary", token=TOKEN).json()
    assert [a["active"] for a in summary["arms"]] == [QUOTA] * 4

    for pid in pids[:5]:  # the page's play socket too (it carries the cookie)
        with socket_to(study_cluster, {ROUTE_COOKIE: pid}) as ws:
            assert ws.response.headers[BACKEND_HEADER] == backends[pid]
            ws.send(json.dumps({"type": "ping"}))


def test_health_through_the_proxy_reports_every_backend(study_cluster):
    answers = [study_cluster.request("/api/health", cookies={ROUTE_COOKIE: f"p{i}"}) for i in range(12)]
    assert {a.headers[BACKEND_HEADER] for a in answers} == {"b1", "b2", "b3"}
    for answer in answers:  # whichever backend answers, it reports them all
        health = answer.json()
        assert health["backend"] == answer.headers[BACKEND_HEADER]
        assert [b["name"] for b in health["backends"]] == ["b1", "b2", "b3"]
        assert all(b["up"] and b["ready"] and "tick_lateness_p99_ms" in b for b in health["backends"])
        assert health["cluster"]["size"] == health["cluster"]["up"] == 3
    assert len({b["pid"] for b in answers[0].json()["backends"]}) == 3
    summary = study_cluster.request("/api/study/admin/summary", token=TOKEN).json()
    assert [b["name"] for b in summary["backends"]] == ["b1", "b2", "b3"] and summary["live_games"] == 0
