"""Servo buses and backends against their emulators over real pseudo-terminals.

``BUS_LATENCY_MS`` is the USB latency timer these tests give a bus whose assertions count lost
replies: the suite runs on two workers over two cores, and the emulator's thread can then wait some
tens of milliseconds for a core, which a 16 ms timer (a 34 ms reply timeout) would count as a lost
reply. Only the replies a test makes late or drops on purpose time out; each costs 2 x 100 ms.
"""

BUS_LATENCY_MS = 100.0
