"""Who is asking: bearer API keys from ``SCANMILL_API_KEYS``, or anonymous on loopback only.

With keys configured, every jobs request needs ``Authorization: Bearer KEY`` (401 otherwise).
Without keys the service warns at start and accepts anonymous requests from loopback clients
only (403 for others); who the client is follows :func:`client_address` (proxy headers are
believed only from the proxies in ``SCANMILL_FORWARDED_ALLOW_IPS``). A job belongs to the key that
created it: the owner stored with the job is a hash of the key (the key itself is never stored),
and other keys get 404 for it.
"""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
from dataclasses import dataclass
from functools import lru_cache
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers

from service.problems import ApiError
from service.settings import Settings

ANONYMOUS = "anonymous"

bearer_scheme = HTTPBearer(auto_error=False, scheme_name="ApiKey",
                           description="An API key from SCANMILL_API_KEYS, as `Authorization: Bearer KEY`.")


@dataclass(frozen=True)
class Principal:
    """The caller: ``owner`` is the stable id jobs are stored under."""

    owner: str
    anonymous: bool


def owner_of_key(key: str) -> str:
    """The owner id of an API key (a SHA-256 prefix; the key is never stored)."""
    return "key-" + hashlib.sha256(key.encode()).hexdigest()[:32]


def _ip(host: str | None) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    if not host:
        return None
    try:
        ip = ipaddress.ip_address(host.split("%")[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped                  # ::ffff:127.0.0.1 is 127.0.0.1
    return ip


def is_loopback(host: str | None) -> bool:
    """Whether a client address is a loopback address (127.0.0.0/8, ::1)."""
    ip = _ip(host)
    if ip is None:
        return host == "localhost"
    return ip.is_loopback


@lru_cache(maxsize=64)
def _allow_list(entries: tuple[str, ...]) -> tuple[bool, tuple[ipaddress.IPv4Network | ipaddress.IPv6Network, ...]]:
    nets = tuple(ipaddress.ip_network(e, strict=False) for e in entries if e != "*")
    return "*" in entries, nets


def is_trusted_proxy(host: str | None, allow: list[str] | tuple[str, ...]) -> bool:
    """Whether ``host`` is in SCANMILL_FORWARDED_ALLOW_IPS (addresses or networks; '*' trusts every peer)."""
    any_peer, nets = _allow_list(tuple(allow))
    if any_peer:
        return True
    ip = _ip(host)
    return ip is not None and any(ip.version == n.version and ip in n for n in nets)


def _strip_port(value: str) -> str:
    """``1.2.3.4:80`` -> ``1.2.3.4``; ``[2001:db8::1]:80`` -> ``2001:db8::1``; others unchanged."""
    v = value.strip().strip('"').strip()
    if v.startswith("["):
        end = v.find("]")
        return v[1:end] if end > 0 else v
    if v.count(":") == 1:
        return v.split(":", 1)[0]
    return v


def _forwarded_for(value: str) -> list[str]:
    """The ``for=`` nodes of an RFC 7239 ``Forwarded`` header, first hop first ('' for an element without one)."""
    nodes = []
    for element in value.split(","):
        node = ""
        for pair in element.split(";"):
            name, _, v = pair.partition("=")
            if name.strip().lower() == "for":
                node = _strip_port(v)
        nodes.append(node)
    return nodes


def _client_from_chain(chain: list[str], allow: list[str]) -> str:
    """The right-most address of a proxy chain that is not itself a trusted proxy (the left-most if all are)."""
    for host in reversed(chain):
        if not is_trusted_proxy(host, allow):
            return host
    return chain[0]


def client_address(scope_client: tuple[str, int] | None, headers: Headers | dict, settings: Settings) -> str | None:
    """The client's address, by the one rule of this service (also used for the anonymous-loopback rule).

    The socket peer decides, unless it is a proxy named in SCANMILL_FORWARDED_ALLOW_IPS: then its
    client-address headers are believed, RFC 7239 ``Forwarded`` (``for=``), ``X-Forwarded-For`` and
    ``X-Real-IP``, and from each the right-most address that is not itself a trusted proxy is taken.
    When several of those headers are present and they disagree, the one naming a non-loopback
    client wins (a client could have added the others itself), and a ``for=`` that is no address
    (``unknown``, an obfuscated name) counts as a remote client. uvicorn's own proxy-header handling
    is off (``scanmill serve``), so nothing else rewrites the client.
    """
    peer = scope_client[0] if scope_client else None
    allow = settings.forwarded_allow_ips
    if not is_trusted_proxy(peer, allow):
        return peer
    get_all = headers.getlist if hasattr(headers, "getlist") else (lambda k: [headers[k]] if k in headers else [])
    candidates: list[str] = []
    fwd = [n for v in get_all("forwarded") for n in _forwarded_for(v)]
    if fwd:
        candidates.append(_client_from_chain(fwd, allow))
    xff = [_strip_port(h) for v in get_all("x-forwarded-for") for h in v.split(",")]
    if xff:
        candidates.append(_client_from_chain(xff, allow))
    real = [_strip_port(v) for v in get_all("x-real-ip")]
    if real:
        candidates.append(real[-1])
    if not candidates:
        return peer
    for c in candidates:
        if not is_loopback(c):
            return c
    return candidates[0]


async def get_settings(request: Request) -> Settings:
    """The running service's settings (dependency)."""
    return request.app.state.settings


async def get_principal(request: Request,
                        credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer_scheme)],
                        settings: Annotated[Settings, Depends(get_settings)]) -> Principal:
    """Authenticate the request (dependency); raises 401/403 problems."""
    if settings.api_keys:
        if credentials is None or credentials.scheme.lower() != "bearer" or not credentials.credentials:
            raise ApiError(401, "unauthenticated",
                           "This service needs an API key: send `Authorization: Bearer KEY`.",
                           headers={"WWW-Authenticate": 'Bearer realm="scanmill"'})
        given = credentials.credentials.encode()
        for key in settings.api_keys:
            if hmac.compare_digest(given, key.encode()):
                return Principal(owner=owner_of_key(key), anonymous=False)
        raise ApiError(401, "invalid_api_key", "The API key is not valid for this service.",
                       headers={"WWW-Authenticate": 'Bearer realm="scanmill", error="invalid_token"'})
    client = client_address(request.scope.get("client"), request.headers, settings)
    if not is_loopback(client):
        raise ApiError(403, "anonymous_not_allowed",
                       "This service has no API keys configured (SCANMILL_API_KEYS) and accepts anonymous "
                       "requests from the local machine only.")
    return Principal(owner=ANONYMOUS, anonymous=True)
