"""Which process holds a TCP port or a device link: a real listening socket, a real pty."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

from tiplog.holders import device_reader, pty_emulator, tcp_listener


def test_a_listening_socket_names_this_process():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        assert tcp_listener(port, "127.0.0.1") is None  # bound, not listening
        s.listen()
        h = tcp_listener(port, "127.0.0.1")
        assert h is not None and h.pid == os.getpid() and "python" in h.cmdline
        assert tcp_listener(port, "127.0.0.2") is None  # another loopback address is free
        assert tcp_listener(port, "0.0.0.0").pid == os.getpid()  # the wildcard would collide
    assert tcp_listener(port, "127.0.0.1") is None


def test_a_pty_link_names_its_emulator_and_its_reader_and_a_stale_link_nobody(tmp_path):
    link = tmp_path / "device"
    assert pty_emulator(link) is None and device_reader(link) is None
    master, slave = os.openpty()
    os.symlink(os.ttyname(slave), link)
    os.close(slave)
    try:
        assert pty_emulator(link).pid == os.getpid()
        assert device_reader(link) is None  # nobody else has the slave open
        reader = subprocess.Popen(
            [
                sys.executable,
                "-c",
                f"import sys; f = open({str(link)!r}, 'rb'); sys.stdout.write('ok\\n'); "
                "sys.stdout.flush(); sys.stdin.read()",
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert reader.stdout.readline() == "ok\n"
            assert device_reader(link).pid == reader.pid
        finally:
            reader.stdin.close()
            reader.wait(10)
    finally:
        os.close(master)
    assert pty_emulator(link) is None  # the pty is gone with its master: a stale link
