"""The pty emulator: a pyserial host reads exactly the intact frames; unplug removes the
link and the host sees the port go; replug brings a new pty behind the same path."""

from __future__ import annotations

import itertools
import threading

import pytest
import serial

from tiplog.devproto.emulator import DeviceEmulator, FaultConfig
from tiplog.devproto.parser import StreamParser
from tiplog.devproto.synthetic import synthetic_packets


def _read_until(port: serial.SerialBase, parser: StreamParser, n: int) -> list:
    out: list = []
    for _ in range(2000):
        out += parser.feed(port.read(port.in_waiting or 1))
        if len(out) >= n:
            break
    return out


def test_host_reads_the_intact_frames_with_faults(tmp_path):
    link = tmp_path / "dev"
    faults = FaultConfig(garbage_prob=0.1, truncate_prob=0.05, bitflip_prob=0.05, drop_prob=0.05, seed=2)
    with DeviceEmulator(link, faults, record=True) as emu:
        assert link.is_symlink()
        port = serial.serial_for_url(str(link), timeout=0.5)
        parser = StreamParser()
        packets = synthetic_packets(emu.rates_hz, seed=4)

        def write() -> None:
            for pkt in itertools.islice(packets, 3000):
                emu.send(pkt)

        writer = threading.Thread(target=write)
        writer.start()
        want = None
        got = []
        while want is None or len(got) < len(want):
            got += parser.feed(port.read(port.in_waiting or 1))
            if want is None and not writer.is_alive():
                want = [(w.stream, w.seq, w.device_us) for w in emu.ledger if w.reached]
        writer.join()
        port.close()
    assert [(p.type.name.lower(), p.seq, p.device_us) for p in got] == want
    assert want[0][0] == "hello"  # the handshake comes first
    assert {w.fate for w in emu.ledger} == {"intact", "truncated", "bitflip", "dropped"}
    assert parser.faults["seq_gap_samples"] >= emu.stats["dropped"]


def test_unplug_removes_the_link_and_the_host_sees_it(tmp_path):
    link = tmp_path / "dev"
    emu = DeviceEmulator(link)
    emu.plug()
    port = serial.serial_for_url(str(link), timeout=0.5)
    emu.send_gyro(1000, (0.1, 0.2, 0.3))
    parser = StreamParser()
    got = _read_until(port, parser, 2)
    assert [p.type.name for p in got] == ["HELLO", "GYRO"]
    emu.unplug()
    assert not link.exists()
    with pytest.raises(serial.SerialException):
        for _ in range(100):
            port.read(1)
    port.close()
    emu.send_gyro(2000, (0, 0, 0))  # unplugged: never written
    assert emu.stats["unplugged"] == 1
    emu.plug()
    port = serial.serial_for_url(str(link), timeout=0.5)
    emu.send_accel(3000, (0, 0, 9.8))
    got = _read_until(port, parser, 2)
    assert [p.type.name for p in got] == ["HELLO", "ACCEL"]
    port.close()
    emu.close()
    assert not link.exists()


def test_fault_config_checks_its_fields():
    with pytest.raises(ValueError, match="bitflip_prob"):
        FaultConfig(bitflip_prob=1.5)
