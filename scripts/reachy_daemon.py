"""Start Reachy Mini's daemon (PyPI ``reachy-mini``) without its mDNS announcements.

The daemon always registers ``_reachy-mini._tcp.local.`` with zeroconf, which multicasts on every
interface and has no flag to turn it off; this launcher stubs the registration out, then runs the
daemon's own ``main`` with the same arguments as ``reachy-mini-daemon``. Run it with the Python of
the daemon's venv (``.venv-reachy``, made by ``scripts/setup.sh --dev``), and with
``DO_NOT_TRACK=1`` for no telemetry (``tests/backends/reachy/conftest.py`` sets both up).
A simulated robot, headless and offline, on 127.0.0.1::

    DO_NOT_TRACK=1 .venv-reachy/bin/python scripts/reachy_daemon.py --mockup-sim --headless \\
        --no-media --dataset-update-interval 0 --no-goto-sleep-on-stop
"""

import sys

from reachy_mini.utils import discovery

discovery.MdnsServiceRegistration.register = lambda self: None  # type: ignore[method-assign]
discovery.MdnsServiceRegistration.unregister = lambda self: None  # type: ignore[method-assign]

from reachy_mini.daemon.app.main import main  # noqa: E402 (after the stub)

sys.exit(main())
