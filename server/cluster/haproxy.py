"""HAProxy in front of the backends: its configuration (a file a researcher can read and reuse) and its binary.

Who goes where: a participant's link carries their id (the study's ``id_params``, ``PROLIFIC_PID`` or ``pid``),
and the study page answers with a cookie holding it (``colorgrid_route``), which every later request of the
page carries (its API calls, its play socket); free play's page sets the cookie to an id of the browser's own.
HAProxy hashes that key on a consistent-hash ring: every request of one participant reaches one backend, and
when a backend goes down only its participants move (to the others), and back when it returns. A waiting
room lives in the backend that opened it: a page opened at ``/?room=CODE`` on another backend is sent, by a
second cookie naming the room's backend (``colorgrid_backend``), to that one (``server.cluster.siblings``); so
is a study page whose game still runs on another backend than the one its key hashes to (one started again after
it died takes its participants back while their games run where they went meanwhile).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

from server.cluster.plan import ClusterPlan
from server.settings import ServerSettings

HAPROXY_ENV = "COLORGRID_HAPROXY"
"""Names the HAProxy binary to run, when not Debian's on PATH."""
ROUTE_COOKIE = "colorgrid_route"
"""The key HAProxy hashes: the participant id (a study) or the browser's own id (free play)."""
BACKEND_COOKIE = "colorgrid_backend"
"""Names a backend (``b2``) that must serve this browser whatever the hash says: the one holding its room, or
running its participant's game."""
BACKEND_HEADER = "X-ColorGrid-Backend"
"""Added by HAProxy to every answer: the backend that gave it."""
HEALTH_CHECK = "/api/health?scope=backend"
"""What HAProxy asks each backend every second: 200 once it is ready, 503 before."""
PLAIN_HOST = "127.0.0.1"
"""The ``Host`` a health check (and a backend asking a sibling) sends: every server answers it."""
TUNNEL_MARGIN_S = 60
"""How much longer than the longest silence of a play socket the proxy keeps it open."""
CLUSTER_PATH = "/api/cluster/"
"""Where the backends ask each other (``server.cluster.siblings``): the proxy refuses it from outside."""


def haproxy_binary() -> str:
    """Debian's ``haproxy`` (on PATH, or in /usr/sbin), or the one ``COLORGRID_HAPROXY`` names; a ``ValueError``
    saying how to install it when there is none."""
    named = os.environ.get(HAPROXY_ENV)
    found = (shutil.which(named) if named else
             shutil.which("haproxy") or shutil.which("haproxy", path="/usr/sbin:/usr/local/sbin"))
    if found is None and named:
        raise ValueError(f"{HAPROXY_ENV}={named} is not a program that can be run: name HAProxy's binary, or unset it")
    if found is None:
        raise ValueError("several processes need HAProxy in front of them, and haproxy is not installed: "
                         "apt-get install haproxy (or make services), or run one process (--processes 1)")
    return found


def tunnel_timeout_s(settings: ServerSettings) -> int:
    """How long an open play socket may stay silent: a turn-based game waits on a key up to ``idle_timeout_s``, a
    room for its people up to ``room_wait_s``; never less than an hour."""
    silent = max(settings.idle_timeout_s, settings.room_wait_s, settings.connection_idle_s, settings.rejoin_grace_s)
    return int(max(3600, silent + TUNNEL_MARGIN_S))


def proxy_config(plan: ClusterPlan, settings: ServerSettings, id_params: tuple[str, ...] = ()) -> str:
    """The configuration for ``plan``'s backends, every line explained. ``id_params``: the URL parameters that
    carry a participant's id (a study's), hashed before the cookie; ``settings``: the backends' (timeouts)."""
    bind = {"0.0.0.0": "", "::": "[::]"}.get(plan.public_host, plan.public_host)
    bind = f"[{bind}]" if ":" in bind and not bind.startswith("[") else bind
    keys = [f"url_param({name})" for name in id_params] + [f"req.cook({ROUTE_COOKIE})"]
    first = "the participant id in the link" if id_params else "the browser's own id"
    lines = [
        ("global", ""),
        (f"maxconn {max(2000, 2 * len(plan.members) * settings.max_connections)}",
         "open connections in all (a play socket holds two)"),
        ("noreuseport", "the port is this proxy's alone: a second one there fails to start"),
        ("", ""),
        ("defaults", ""),
        ("mode http", ""),
        ("option forwardfor", "the backends see each person's address (X-Forwarded-For)"),
        ("option redispatch", "a request whose backend is down goes to another..."),
        ("retries 2", "...after two failed tries..."),
        ("retry-on conn-failure empty-response", "...to connect, or to get an answer (a killed process)"),
        ("timeout connect 2s", "a backend that does not accept within 2 s has failed"),
        (f"timeout http-request {settings.header_timeout_s:g}s", "a request's headers must arrive within this"),
        ("timeout client 60s", "an idle HTTP client is closed"),
        ("timeout server 300s", "the slowest answer (the admin's data download)"),
        (f"timeout tunnel {tunnel_timeout_s(settings)}s",
         "a play socket may stay silent this long (not a game's length)"),
        ("timeout check 5s", "a health check's answer"),
        ("", ""),
        ("frontend colorgrid", ""),
        (f"bind {bind}:{plan.public_port}", "where people connect"),
        ("", "the backends' questions to each other (/api/cluster/) stay inside, however the path is written:"),
        ("", "the path as the backends read it (percent-decoded), and one that does not decode is refused"),
        ("http-request set-var(txn.path) path,url_dec", ""),
        ("http-request deny deny_status 400 if { path -m sub % } !{ var(txn.path) -m found }", ""),
        (f"http-request deny if {{ var(txn.path) -m beg {CLUSTER_PATH} }}", ""),
        ("default_backend play_servers", ""),
        ("", ""),
        ("backend play_servers", ""),
        ("", f"the key: {first}, else the cookie the pages set (the same id, or the browser's own)"),
        (f"http-request set-var(txn.route) {keys[0]}", ""),
        *[(f"http-request set-var(txn.route) {key} unless {{ var(txn.route) -m found }}", "") for key in keys[1:]],
        ("balance hash var(txn.route)", "one key, one backend (no key yet: round robin)"),
        ("hash-type consistent", "a backend going down moves only its own keys"),
        (f"cookie {BACKEND_COOKIE}", "sent to the backend with its room or game (the backends set it)"),
        ("option httpchk", "health: each backend is asked how it is..."),
        (f"http-check send meth GET uri {HEALTH_CHECK} hdr Host {PLAIN_HOST}", ""),
        ("http-check expect status 200", "...503 while it loads its followers: none sent yet"),
        ("", "every second; down after 2 failed checks, or at once after 2 refused connections (a killed process);"),
        ("", "up again after 2 good checks"),
        ("default-server check inter 1s fall 2 rise 2 observe layer4 error-limit 2 on-error mark-down", ""),
        (f"http-response set-header {BACKEND_HEADER} %[srv_name]", "which backend answered"),
        *[(f"server {m.name} {m.address} cookie {m.name}", "") for m in plan.members],
    ]
    head = ["# HAProxy in front of ColorGrid play servers, written by colorgrid: see docs/STUDIES.md, \"Running a",
            "# large study\". Run it with `haproxy -f haproxy.cfg` (`colorgrid ... --processes N` runs it itself)."]
    body = []
    for text, note in lines:
        indent = "" if text in ("global", "defaults") or text.startswith(("frontend", "backend")) else "    "
        if not text and note:
            body.append(f"    # {note}")
        elif note:
            body.append(f"{indent}{text:<52} # {note}")
        else:
            body.append(f"{indent}{text}".rstrip())
    return "\n".join([*head, *body, ""])


HAPROXY_LINE = re.compile(r"^\[(?P<level>[A-Z]+)\]\s*\(\d+\)\s*:\s*(?P<text>.*)$")
"""A line HAProxy writes to its standard error: ``[WARNING]  (1234) : text``."""
SERVER_STATE = re.compile(r"^Server [^/\s]+/(?P<server>\S+) is (?P<state>DOWN|UP)\b(?:, reason: (?P<reason>[^,]+))?"
                          r"(?:, info: \"(?P<info>[^\"]*)\")?")


def haproxy_said(line: str) -> str | None:
    """What the launcher says of a line of HAProxy's output: a backend down or up again in words; no backend left up
    in words; the proxies stopping on the launcher's soft stop (a normal stop) not at all; anything else as HAProxy
    wrote it, with its level."""
    found = HAPROXY_LINE.match(line.strip())
    if found is None:
        return f"haproxy: {line.strip()}" if line.strip() else None
    level, text = found["level"], found["text"].strip()
    if text.startswith("Proxy ") and " stopped (" in text:
        return None
    state = SERVER_STATE.match(text)
    if state is not None and state["state"] == "DOWN":
        why = ": ".join(part for part in (state["reason"], state["info"]) if part)
        return f"haproxy: {state['server']} is down ({why}); its participants go to the other backends"
    if state is not None:
        return f"haproxy: {state['server']} is up again"
    if text.endswith("has no server available!"):
        return "haproxy: no backend is up: people get an error page until one is back"
    return f"haproxy: {level.lower()}: {text}"


def check_config(binary: str, path: Path) -> None:
    """``haproxy -c``: a configuration HAProxy refuses is a ``ValueError`` with HAProxy's own words."""
    result = subprocess.run([binary, "-c", "-q", "-f", str(path)], capture_output=True, text=True, timeout=30)
    if result.returncode != 0:
        words = " ".join((result.stderr or result.stdout).split())
        raise ValueError(f"HAProxy refuses {path}: {words[:500]}")
