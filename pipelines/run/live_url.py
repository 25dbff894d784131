"""A `--live-url`, parsed by gslam rather than urllib, so that a bad port or an IPv6 address without
brackets is said in gslam's words (the run's options check it before the run; `pipelines.outputs.rerun_viewer`
asks the endpoint)."""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass

_SCHEMES = {"rerun": False, "rerun+http": False, "rerun+https": True}
"""The schemes of a Rerun gRPC address, and whether each is TLS."""
_LABEL = r"[A-Za-z0-9_]([A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"
_HOST_NAME = re.compile(rf"(?=.{{1,253}}$){_LABEL}(\.{_LABEL})*\.?")
"""A host name or an IPv4 address (dot-separated labels of letters, digits, hyphens and underscores)."""


@dataclass(frozen=True)
class LiveAddress:
    """A Rerun viewer's gRPC address, parsed: `rerun+http://HOST:PORT/proxy`."""

    host: str
    """A host name, or an IPv4 or IPv6 address (without the brackets)."""
    port: int
    tls: bool
    """rerun+https."""


def parse_live_url(url: str) -> LiveAddress:
    """Parse `SCHEME://HOST[:PORT]/proxy` (SCHEME rerun+http, rerun+https or rerun; HOST a name, an IPv4
    address or an IPv6 one in brackets, `[::1]`; PORT 1 to 65535, 9876 when left out). Raises ValueError
    saying what is wrong, in words a user can act on (the caller names the option)."""
    form = "the form is rerun+http://HOST:PORT/proxy, e.g. rerun+http://127.0.0.1:9876/proxy"
    scheme, sep, rest = url.partition("://")
    if not sep or scheme not in _SCHEMES:
        raise ValueError(f"not a Rerun gRPC address ({form})")
    authority, _, path = rest.partition("/")
    if path.rstrip("/") != "proxy":
        raise ValueError(f"the path must be /proxy ({form})")
    if authority.startswith("["):
        host, close, port_text = authority[1:].partition("]")
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(f"{host!r} in brackets is not an IPv6 address ({form})") from None
        if not close or (port_text and not port_text.startswith(":")):
            raise ValueError("an IPv6 address goes in brackets, then :PORT, e.g. rerun+http://[::1]:9876/proxy")
        port_text = port_text[1:]
    else:
        if authority.count(":") > 1:
            raise ValueError("an IPv6 address goes in brackets, e.g. rerun+http://[::1]:9876/proxy")
        host, colon, port_text = authority.partition(":")
        if colon and not port_text:
            raise ValueError(f"no port after the colon ({form})")
        if not host:
            raise ValueError(f"no host name or address before the port ({form})")
        if not _HOST_NAME.fullmatch(host):
            raise ValueError(f"{host[:40]!r} is not a host name or an address ({form})")
    if not port_text:
        port = 9876
    elif not port_text.isascii() or not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"the port must be a number from 1 to 65535, got {port_text[:20]!r}")
    else:
        port = int(port_text)
    return LiveAddress(host, port, _SCHEMES[scheme])
