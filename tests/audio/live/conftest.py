"""The live-audio tests run against their own PulseAudio servers (``tests.pulse``)."""

from tests.pulse import pulse  # noqa: F401 (the fixture, for this folder's tests)
