"""bench train's network relay (chainsim.tools.bench.delay_proxy): every byte arrives, in order, both ways,
and none sooner than half the round trip asked for."""

from __future__ import annotations

import socket
import socketserver
import threading
import time

from chainsim.tools.bench.delay_proxy import DelayProxy


class _EchoServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    block_on_close = False  # a connection the relay left open never holds the test up


class _Echo(socketserver.BaseRequestHandler):
    def handle(self):
        while data := self.request.recv(4096):
            self.request.sendall(data)


def test_the_relay_carries_every_byte_in_order_and_not_before_its_delay():
    server = _EchoServer(("127.0.0.1", 0), _Echo)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    relay = DelayProxy(server.server_address[1], rtt_ms=120)
    try:
        with socket.create_connection(("127.0.0.1", relay.port), timeout=10) as c:
            sent = bytes(range(256)) * 400  # more than one read's worth
            t0 = time.monotonic()
            c.sendall(sent)
            got = b""
            first = None
            while len(got) < len(sent):
                chunk = c.recv(65536)
                assert chunk, "the relay closed early"
                first = first or time.monotonic()
                got += chunk
            assert got == sent
            assert first - t0 >= 0.12 - 0.005  # half the round trip there, half back
    finally:
        relay.close()
        server.shutdown()
        server.server_close()
