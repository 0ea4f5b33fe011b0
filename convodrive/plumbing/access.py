"""Who may reach what a run serves on the network (the ``stream`` page, the ``--self`` socket).

On loopback only this machine can connect, and nothing more is asked. Off loopback a token is
needed: the user's own, or a fresh one the run prints. A loopback server also answers only to
loopback host names, so a web page whose name was re-pointed at 127.0.0.1 (DNS rebinding) is
refused.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARDS = frozenset({"0.0.0.0", "::", ""})


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def token_problem(token: str) -> str | None:
    """Why ``token`` will not do as one (too short, not printable ASCII); None when it will."""
    if len(token) < 8 or not token.isascii() or not token.isprintable() or any(c.isspace() for c in token):
        return "a token must be at least 8 printable ASCII characters, without spaces"
    return None


def token_for(host: str, given: str | None) -> str | None:
    """The token a server bound to ``host`` asks for: ``given``, else none on loopback, else a fresh one."""
    if given is not None:
        return given
    return None if is_loopback(host) else secrets.token_urlsafe(16)


def token_matches(given: str | bytes, token: str) -> bool:
    """Compared in constant time, so the reply's timing says nothing of the token."""
    data = given.encode("utf-8", "replace") if isinstance(given, str) else given
    return hmac.compare_digest(data, token.encode())


def host_allowed(header: str, bound: str) -> bool:
    """Whether an HTTP ``Host`` header names the server bound to ``bound``: a loopback name, or
    the bound address itself. A server on every interface (0.0.0.0, ::) answers to any name,
    since its token guards it."""
    if bound in WILDCARDS:
        return True
    name = header.strip().lower()
    if name.startswith("["):  # [::1]:8765
        name = name[1 : name.find("]")] if "]" in name else ""
    elif name.count(":") == 1:
        name = name.split(":", 1)[0]
    return bool(name) and (name in LOOPBACK_NAMES or name == bound.lower())
