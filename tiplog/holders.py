"""Which process holds a TCP port or a pseudo-terminal device link (Linux `/proc`).

`tiplog up` asks before it starts, so that a second instance (or the orphans of one killed
with SIGKILL) is named in one line instead of being fought over the router endpoint, the
dashboard port or the device link. Only processes this user may inspect are found; the
answer is None where nothing (visible) holds the resource.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from dataclasses import dataclass
from pathlib import Path

PROC = Path("/proc")
_TCP_LISTEN = "0A"


@dataclass(frozen=True, slots=True)
class Holder:
    """A process holding a resource: its pid and command line (shortened)."""

    pid: int
    cmdline: str

    def __str__(self) -> str:
        return f"pid {self.pid} ({self.cmdline})"


def _cmdline(pid: int, limit: int = 80) -> str:
    try:
        raw = (PROC / str(pid) / "cmdline").read_bytes()
    except OSError:
        return "?"
    text = " ".join(a.decode(errors="replace") for a in raw.split(b"\0") if a)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _pids() -> list[int]:
    try:
        return sorted(int(p.name) for p in PROC.iterdir() if p.name.isdigit())
    except OSError:
        return []


def _fd_targets(pid: int) -> list[tuple[str, str]]:
    """(fd number, link target) of every open descriptor of `pid` this user may read."""
    fd_dir = PROC / str(pid) / "fd"
    try:
        names = os.listdir(fd_dir)
    except OSError:
        return []
    out = []
    for fd in names:
        try:
            out.append((fd, os.readlink(fd_dir / fd)))
        except OSError:
            continue
    return out


def _listening_inodes(port: int, host: str | None) -> set[str]:
    """Socket inodes listening on TCP `port` (at `host`, or at a wildcard address covering it)."""
    want: set[str] = set()
    for table, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        try:
            lines = (PROC / "net" / table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            cols = line.split()
            if len(cols) < 10 or cols[3] != _TCP_LISTEN:
                continue
            addr_hex, port_hex = cols[1].split(":")
            if int(port_hex, 16) != port:
                continue
            if host is None or _covers(_proc_addr(addr_hex, family), host):
                want.add(cols[9])
    return want


def _proc_addr(addr_hex: str, family: int) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    raw = bytes.fromhex(addr_hex)
    # /proc/net/tcp* prints each 32-bit word in host (little-endian) byte order
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return ipaddress.IPv4Address(words) if family == socket.AF_INET else ipaddress.IPv6Address(words)


def _covers(bound: ipaddress.IPv4Address | ipaddress.IPv6Address, host: str) -> bool:
    if bound.is_unspecified:
        return True
    try:
        want = ipaddress.ip_address("127.0.0.1" if host == "localhost" else host)
    except ValueError:
        return True  # a host name: any listener on the port is in the way
    if isinstance(bound, ipaddress.IPv6Address) and bound.ipv4_mapped is not None:
        bound = bound.ipv4_mapped
    return bound == want or want.is_unspecified


def tcp_listener(port: int, host: str | None = None) -> Holder | None:
    """The process listening on TCP `port` (at `host` or a wildcard), or None."""
    inodes = {f"socket:[{i}]" for i in _listening_inodes(port, host)}
    if not inodes:
        return None
    for pid in _pids():
        if any(t in inodes for _, t in _fd_targets(pid)):
            return Holder(pid, _cmdline(pid))
    return Holder(0, "a process this user cannot inspect")


def pty_emulator(link: str | os.PathLike[str]) -> Holder | None:
    """The live process holding the master of the pseudo-terminal a device link (a symlink to
    `/dev/pts/N`) points at: an emulator such as the bench. None when the link is absent,
    dangling or not a pseudo-terminal, or when nobody holds it (a stale link)."""
    target = os.path.realpath(link)
    if not Path(link).is_symlink() or not target.startswith("/dev/pts/") or not os.path.exists(target):
        return None
    index = target.rsplit("/", 1)[1]
    for pid in _pids():
        for fd, t in _fd_targets(pid):
            if t == "/dev/ptmx" and _tty_index(pid, fd) == index:
                return Holder(pid, _cmdline(pid))
    return None


def device_reader(path: str | os.PathLike[str]) -> Holder | None:
    """A live process with the device `path` (or what its link points at) open: a reader of a
    serial port or of a pseudo-terminal's slave. None when nobody has it open."""
    if not os.path.exists(path):
        return None
    target = os.path.realpath(path)
    if not target.startswith("/dev/"):
        return None
    for pid in _pids():
        if pid != os.getpid() and any(t == target for _, t in _fd_targets(pid)):
            return Holder(pid, _cmdline(pid))
    return None


def _tty_index(pid: int, fd: str) -> str | None:
    try:
        for line in (PROC / str(pid) / "fdinfo" / fd).read_text().splitlines():
            if line.startswith("tty-index:"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None
