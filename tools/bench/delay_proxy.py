"""A TCP relay that holds every byte for half a round trip each way: `chainsim bench train --rtt-ms`.

The browser trainer is used over networks with tens to hundreds of milliseconds of round trip, not
over loopback. The benchmark puts this relay between the tabs and the records server, so each
message from the page reaches the server `rtt / 2` later and each picture the page `rtt / 2` later,
in order, as on a long link with room to spare (bandwidth is not limited: the trainer's stream needs
little, see docs/records-server.md). It runs its own asyncio loop on a daemon thread.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time


class DelayProxy:
    """``DelayProxy(target_port, rtt_ms)``; ``.port`` is where to connect; ``.close()`` stops it."""

    def __init__(self, target_port: int, rtt_ms: float, host: str = "127.0.0.1") -> None:
        self.target = (host, int(target_port))
        self.delay = max(float(rtt_ms), 0.0) / 2e3
        self.port = 0
        self._writers: set = set()  # every open connection's two ends, closed with the relay
        self._loop = asyncio.new_event_loop()
        started = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(host, started), daemon=True, name="delay-proxy")
        self._thread.start()
        if not started.wait(10):
            raise RuntimeError("the delay relay did not start")

    def _run(self, host: str, started: threading.Event) -> None:
        asyncio.set_event_loop(self._loop)
        server = self._loop.run_until_complete(asyncio.start_server(self._client, host, 0))
        self.port = server.sockets[0].getsockname()[1]
        started.set()
        self._loop.run_forever()
        # stopped (close): what was still relaying is cancelled and waited for before the loop closes
        tasks = asyncio.all_tasks(self._loop)
        for task in tasks:
            task.cancel()
        self._loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
        server.close()
        self._loop.run_until_complete(server.wait_closed())
        self._loop.close()

    async def _client(self, reader, writer) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.target)
        except OSError:
            writer.close()
            return
        self._writers.update((writer, up_writer))
        try:
            await asyncio.gather(self._pipe(reader, up_writer), self._pipe(up_reader, writer))
        finally:
            self._writers.difference_update((writer, up_writer))

    async def _pipe(self, reader, writer) -> None:
        """Bytes from `reader` to `writer`, each chunk sent `delay` after it arrived, in order."""
        queue: asyncio.Queue = asyncio.Queue()

        async def later() -> None:
            while (item := await queue.get()) is not None:
                due, data = item
                wait = due - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                writer.write(data)
                with contextlib.suppress(ConnectionError):
                    await writer.drain()
            writer.close()

        sender = asyncio.ensure_future(later())
        try:
            while data := await reader.read(1 << 16):
                queue.put_nowait((time.monotonic() + self.delay, data))
        except ConnectionError:
            pass
        queue.put_nowait(None)
        await sender

    def close(self) -> None:
        """Close every connection still open (both its ends see the end of the stream), then stop."""

        def shut() -> None:
            for writer in list(self._writers):
                writer.close()
            self._loop.stop()

        self._loop.call_soon_threadsafe(shut)
        self._thread.join(5)
