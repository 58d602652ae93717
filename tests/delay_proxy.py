"""A network as participants have it, on loopback: a TCP proxy that delays every byte, each way, by a latency with
jitter (150 ms +- 30 ms by default: a round trip of about 300 ms). It passes whatever runs over TCP, HTTP and the play
WebSocket alike, byte for byte and in order (jitter never reorders: a chunk is never delivered before the one read
before it). The browser tests (tests/test_page_connections.py) and ``bench/bench_latency.py`` put it between chromium
and a real server.

    with DelayProxy(server_port, delay_s=0.15, jitter_s=0.03) as proxy:
        page.goto(proxy.url + "/study?PROLIFIC_PID=p1")
"""

from __future__ import annotations

import asyncio
import random
import threading

CHUNK = 65536


class DelayProxy:
    """Listens on a free loopback port (``port``, ``url``) and forwards each connection to ``upstream_port``, every
    chunk delivered ``delay_s`` plus a uniform jitter in ``[-jitter_s, jitter_s]`` after it was read. It runs its own
    event loop on a thread: ``start()`` (or ``with``) returns once it listens, ``stop()`` closes every connection."""

    def __init__(self, upstream_port: int, delay_s: float = 0.15, jitter_s: float = 0.03, seed: int = 0,
                 host: str = "127.0.0.1"):
        if not 0 <= jitter_s <= delay_s:
            raise ValueError(f"jitter_s must be in [0, delay_s={delay_s}], got {jitter_s}")
        self.upstream_port, self.delay_s, self.jitter_s, self.host = upstream_port, delay_s, jitter_s, host
        self.rng = random.Random(seed)
        self.port = 0
        self.connections = 0  # connections accepted so far
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._listening = threading.Event()
        self._thread = threading.Thread(target=self._run, name="delay-proxy", daemon=True)
        self._failure: BaseException | None = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def start(self) -> DelayProxy:
        self._thread.start()
        self._listening.wait(10)
        if self._failure is not None or not self.port:
            raise RuntimeError(f"the delay proxy did not start: {self._failure!r}")
        return self

    def stop(self) -> None:
        if self._loop is not None and self._stopping is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stopping.set)
        self._thread.join(10)

    def __enter__(self) -> DelayProxy:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------ the proxy's own thread
    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as err:  # reported by start(), or lost once it stops
            self._failure = err
            self._listening.set()

    async def _serve(self) -> None:
        self._loop, self._stopping = asyncio.get_running_loop(), asyncio.Event()
        tasks: set[asyncio.Task] = set()

        async def accepted(reader, writer):
            task = asyncio.current_task()
            tasks.add(task)
            try:
                await self._connection(reader, writer)
            except asyncio.CancelledError:  # stopping: the connection is closed with the proxy
                pass
            finally:
                tasks.discard(task)

        server = await asyncio.start_server(accepted, self.host, 0)
        self.port = server.sockets[0].getsockname()[1]
        self._listening.set()
        async with server:
            await self._stopping.wait()
            server.close()
            for task in list(tasks):
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _connection(self, client_reader, client_writer) -> None:
        self.connections += 1
        try:
            server_reader, server_writer = await asyncio.open_connection(self.host, self.upstream_port)
        except OSError:
            client_writer.close()
            return
        try:
            await asyncio.gather(self._pipe(client_reader, server_writer), self._pipe(server_reader, client_writer))
        finally:
            for writer in (client_writer, server_writer):
                writer.close()

    def _due(self, after: float) -> float:
        """When a chunk read now is delivered: the delay with its jitter, never before the chunk read before it."""
        jitter = self.rng.uniform(-self.jitter_s, self.jitter_s)
        return max(after, self._loop.time() + self.delay_s + jitter)

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One direction: every chunk read is written ``_due`` later, in order; the end of the stream too."""
        queue: asyncio.Queue = asyncio.Queue()

        async def deliver():
            while True:
                due, chunk = await queue.get()
                await asyncio.sleep(max(0.0, due - self._loop.time()))
                if chunk is None:  # the sender is done: so is this direction
                    if writer.can_write_eof():
                        writer.write_eof()
                    return
                writer.write(chunk)
                await writer.drain()

        delivering = asyncio.create_task(deliver())
        last = 0.0
        try:
            while True:
                chunk = await reader.read(CHUNK)
                last = self._due(last)
                await queue.put((last, chunk or None))
                if not chunk:
                    break
            await delivering
        except (ConnectionError, OSError):
            pass
        finally:
            delivering.cancel()
