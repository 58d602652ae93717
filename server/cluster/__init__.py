"""Several play-server processes behind HAProxy (``colorgrid play|study run --processes N``).

``plan``: who is in a cluster (``cluster.json``); ``haproxy``: the proxy's configuration; ``launcher``: the
parent process that starts the backends and the proxy, restarts a backend that dies and stops them all;
``process``: one backend process; ``siblings``: what a backend does as one of several (the routing cookie,
rooms held by a sibling, the whole cluster's health). See docs/STUDIES.md, "Running a large study".
"""
