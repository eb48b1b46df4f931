"""One shared MAVLink link on loopback, as a process of its own (a radio channel or mavlink-router stands apart from
the test and from our nodes: it must not stall when the test process or the machine is busy).

    python mavlink_hub.py RECORD_FILE BRIDGE_PORT...

Prints one line, the UDP ports the vehicles send to (one per bridge, in order), then relays: every vehicle's
datagram goes to every bridge's udpin port, every bridge's datagram to every vehicle heard so far. Each datagram a
bridge sends is appended to RECORD_FILE as (CLOCK_MONOTONIC s: float64, bridge index: uint32, length: uint32,
bytes), flushed as it goes. Runs under SCHED_FIFO 30 where the system allows it, until SIGTERM."""

import select
import signal
import socket
import struct
import sys
import time

from quad_common.realtime import apply_or_report

RECORD = struct.Struct('<dII')
PRIORITY = 30   # with the emulated vehicles, above our nodes (SCHED_FIFO 20)


def read_record(path):
    """[(monotonic s, bridge index, datagram bytes)] of a RECORD_FILE."""
    data = open(path, 'rb').read()
    out, k = [], 0
    while k + RECORD.size <= len(data):
        t, j, n = RECORD.unpack_from(data, k)
        k += RECORD.size
        if k + n > len(data):
            break
        out.append((t, j, data[k:k + n]))
        k += n
    return out


def main(argv):
    record_path, bridge_ports = argv[0], [int(p) for p in argv[1:]]

    def bound():
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(('127.0.0.1', 0))
        return s
    vehicle_socks = [bound() for _ in bridge_ports]
    bridge_socks = [bound() for _ in bridge_ports]
    bridge_addrs = [('127.0.0.1', p) for p in bridge_ports]
    vehicle_addrs = [None] * len(bridge_ports)
    running = [True]
    signal.signal(signal.SIGTERM, lambda *_: running.__setitem__(0, False))
    apply_or_report(PRIORITY, lambda error: print(f'mavlink_hub: {error}', file=sys.stderr, flush=True))
    print(' '.join(str(s.getsockname()[1]) for s in vehicle_socks), flush=True)
    socks, n = vehicle_socks + bridge_socks, len(vehicle_socks)
    with open(record_path, 'ab', buffering=0) as record:
        while running[0]:
            try:
                ready, _, _ = select.select(socks, [], [], 0.05)
            except InterruptedError:
                continue
            for sock in ready:
                try:
                    data, addr = sock.recvfrom(65536)
                except OSError:
                    continue
                k = socks.index(sock)
                if k < n:                                  # a vehicle: to every bridge
                    vehicle_addrs[k] = addr
                    for out, to in zip(bridge_socks, bridge_addrs):
                        out.sendto(data, to)
                else:                                      # bridge k - n: to every vehicle heard
                    record.write(RECORD.pack(time.monotonic(), k - n, len(data)) + data)
                    for out, to in zip(vehicle_socks, vehicle_addrs):
                        if to is not None:
                            out.sendto(data, to)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
