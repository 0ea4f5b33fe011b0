"""Audio devices through PortAudio (``sounddevice``): loading it, listing, and finding one by name.

PortAudio is imported only by live runs, so ``drive`` works where it is missing; a live run that
needs it and lacks it is one line saying what to install.
"""

from __future__ import annotations

import atexit
import ctypes
import ctypes.util
import dataclasses
import threading
from typing import Any, Literal

from convodrive.plumbing.errors import UserError

Kind = Literal["input", "output"]


def portaudio() -> Any:
    """The ``sounddevice`` module, or a ``UserError`` naming what to install."""
    try:
        _quiet_alsa()
        import sounddevice
    except ImportError:
        raise UserError("live audio needs the sounddevice package: pip install 'convodrive[live]'") from None
    except OSError:  # sounddevice is there, the PortAudio library is not
        raise UserError(
            "live audio needs the PortAudio library: apt-get install libportaudio2 (scripts/setup.sh does)"
        ) from None
    return sounddevice


def close_stream(stream: Any, answering: bool = True) -> None:
    """Abort and close a PortAudio stream, whatever state it is in.

    A stream whose audio server stopped answering (``answering`` False: a playback that stopped
    pulling, a microphone that went silent) can block both calls for good, and PortAudio's exit
    handler after them (it stops the last stream, waiting for it to drain, then terminates the
    library): a daemon thread tries to close it, and that exit handler is dropped, so the run
    still ends and writes its report; the operating system reclaims the device."""
    if answering:
        _abort(stream)
        return
    threading.Thread(target=_abort, args=(stream,), name="close-audio-stream", daemon=True).start()
    sd = portaudio()
    handler = getattr(sd, "_exit_handler", None)
    if handler is not None:
        atexit.unregister(handler)


def _abort(stream: Any) -> None:
    try:
        stream.abort()
        stream.close()
    except Exception:
        pass


_ALSA_HANDLER: Any = None


def _quiet_alsa() -> None:
    """Stop libasound printing its own lines ("underrun occurred", probing messages) on stderr:
    PortAudio reports the same events to us, and the run report counts them."""
    global _ALSA_HANDLER
    if _ALSA_HANDLER is not None:
        return
    try:
        alsa = ctypes.CDLL(ctypes.util.find_library("asound") or "libasound.so.2")
    except OSError:  # no ALSA on this system: nothing to quieten
        _ALSA_HANDLER = False
        return
    prototype = ctypes.CFUNCTYPE(None, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p)
    _ALSA_HANDLER = prototype(lambda *args: None)  # kept referenced: ALSA calls it for the process's life
    alsa.snd_lib_error_set_handler(_ALSA_HANDLER)


@dataclasses.dataclass(frozen=True)
class Device:
    index: int
    name: str
    host_api: str
    inputs: int
    outputs: int
    default_rate: float

    def channels(self, kind: Kind) -> int:
        return self.inputs if kind == "input" else self.outputs


def list_devices() -> list[Device]:
    sd = portaudio()
    apis = [a["name"] for a in sd.query_hostapis()]
    return [
        Device(
            index=i,
            name=str(d["name"]),
            host_api=apis[d["hostapi"]] if d["hostapi"] < len(apis) else "?",
            inputs=int(d["max_input_channels"]),
            outputs=int(d["max_output_channels"]),
            default_rate=float(d["default_samplerate"]),
        )
        for i, d in enumerate(sd.query_devices())
    ]


def default_index(kind: Kind) -> int | None:
    sd = portaudio()
    index = sd.default.device[0 if kind == "input" else 1]
    return None if index is None or int(index) < 0 else int(index)


def describe_devices() -> str:
    """What ``convodrive live --list-devices`` prints: one line a device, defaults marked."""
    devices = list_devices()
    if not devices:
        return "no audio devices (is an audio server running?)"
    default_in, default_out = default_index("input"), default_index("output")
    lines = []
    for d in devices:
        marks = ("<" if d.index == default_in else " ") + (">" if d.index == default_out else " ")
        lines.append(
            f"{marks} {d.index:>3} {d.name} ({d.host_api}; {d.inputs} in, {d.outputs} out; {d.default_rate:g} Hz)"
        )
    lines.append("   < default input, > default output")
    return "\n".join(lines)


def find_device(spec: str, kind: Kind, option: str) -> Device:
    """The device ``spec`` names: an index, ``default``, or a name (exact, else a unique part of one,
    ignoring case). Anything else is a ``UserError`` that names ``option`` and lists the choices."""
    devices = [d for d in list_devices() if d.channels(kind) > 0]
    text = spec.strip()
    if text.lower() == "default":
        index = default_index(kind)
        chosen = [d for d in devices if d.index == index]
    elif text.isdigit():
        chosen = [d for d in devices if d.index == int(text)]
    else:
        chosen = [d for d in devices if d.name.lower() == text.lower()] or [
            d for d in devices if text.lower() in d.name.lower()
        ]
    if len(chosen) == 1:
        return chosen[0]
    if len(chosen) > 1:
        several = ", ".join(f"{d.index} {d.name!r}" for d in chosen)
        raise UserError(f"{option} {spec!r}: names several {kind} devices ({several}); give the index")
    names = ", ".join(f"{d.index} {d.name!r}" for d in devices) or "none"
    raise UserError(f"{option} {spec!r}: no such {kind} device (the {kind} devices: {names})")
