"""A TCP server that sends the same OpenIGTLink bytes to every connected client.

pyigtl's own server serves one client and queues messages while none is connected (a client
that connects later would get stale poses first); this one holds any number of clients
(Slicer and a recorder, say), sends only what is current, and never waits on a client: a
client whose socket does not take a message within `send_timeout_s` is dropped (it may connect
again). What clients send (Slicer's queries, its own transforms) is read and
discarded, so their sockets never fill.
"""

from __future__ import annotations

import logging
import socket
import threading

log = logging.getLogger("tiplog.igtlink")


class BroadcastServer:
    """Listens on (host, port); `broadcast(data)` writes `data` whole to each client."""

    def __init__(self, host: str, port: int, *, send_timeout_s: float = 0.2):
        self._sock = socket.create_server((host, port), reuse_port=False)
        self._sock.settimeout(0.2)
        self.host, self.port = self._sock.getsockname()[:2]
        self._send_timeout_s = send_timeout_s
        self._clients: dict[socket.socket, str] = {}
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self.connections = 0  # clients accepted since start
        self.dropped = 0  # clients dropped for a failed or slow send
        self._accept_thread = threading.Thread(target=self._accept, name="igtl-accept", daemon=True)
        self._accept_thread.start()

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                conn, addr = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(self._send_timeout_s)
            peer = f"{addr[0]}:{addr[1]}"
            with self._lock:
                self._clients[conn] = peer
                self.connections += 1
            log.info("OpenIGTLink client %s connected (%d connected)", peer, self.client_count)
            threading.Thread(target=self._drain, args=(conn,), name=f"igtl-read-{peer}", daemon=True).start()

    def _drain(self, conn: socket.socket) -> None:
        """Read and discard what the client sends until it closes."""
        while not self._closed.is_set():
            try:
                data = conn.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
        self._drop(conn, "disconnected")

    def _drop(self, conn: socket.socket, why: str) -> None:
        with self._lock:
            peer = self._clients.pop(conn, None)
        if peer is None:
            return
        try:
            conn.close()
        except OSError:
            pass
        log.info("OpenIGTLink client %s %s", peer, why)

    def broadcast(self, data: bytes) -> int:
        """Send `data` to every client; returns how many took it whole."""
        with self._lock:
            clients = list(self._clients)
        sent = 0
        for conn in clients:
            try:
                conn.sendall(data)
                sent += 1
            except OSError as e:  # a timeout leaves a partial message: the stream is lost
                self.dropped += 1
                self._drop(conn, f"dropped ({e.__class__.__name__})")
        return sent

    def close(self) -> None:
        self._closed.set()
        try:
            self._sock.close()
        except OSError:
            pass
        self._accept_thread.join(timeout=1.0)
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            self._drop(c, "closed by the server")

    def __enter__(self) -> BroadcastServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
