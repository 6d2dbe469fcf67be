"""Who may open the station (no rclpy, no server): the Host a request names, the WebSocket's Origin and
the token. Checked for the page, every file and the WebSocket handshake.

- **Host names this station** (DNS rebinding, issue 32): a page on any web site whose name the attacker
  then points at 127.0.0.1 reaches the station with its own name in Host (and in Origin: Origin equals
  Host proves nothing, the rebinding page sends both with its own name; Jupyter checks Host as here).
  Only these names are accepted, with the port served: the bind address, ``localhost``,
  ``127.0.0.1``, ``[::1]``, the names the caregiver configures (``hosts``), and, when the station
  listens on every interface, any IP address (a browser sends an IP address as Host only to the
  machine at that address: no other site can rebind an address).
- **Origin** (WebSocket): the page that opens the socket was served by this station (its Host).
- **The token**, on every address, loopback included, as Jupyter does: the Host check stops browsers
  only; any program or other user account on the robot PC can connect to 127.0.0.1 and send any Host.
  Compared in constant time.
"""
from __future__ import annotations

import hmac
import ipaddress
import os
import secrets
import string
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

LOOPBACK = ("127.0.0.1", "::1", "localhost")
WILDCARD = ("0.0.0.0", "::", "")
TOKEN_CHARS = frozenset(string.ascii_letters + string.digits + "-_.~")   # unreserved in a URL
MIN_TOKEN_CHARS = 16
MAX_TOKEN_FILE_BYTES = 4096


class TokenError(ValueError):
    """The token file cannot be used; the message never quotes its content."""


def load_token(path: Path) -> tuple[str, bool]:
    """(the token, whether it was made now): read from ``path``, or, when there is no such file, a new
    random one written there (readable by its owner only), so that a restarted station keeps its address
    and an open page reconnects. TokenError when the file cannot be read or its token cannot be used."""
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_TOKEN_FILE_BYTES + 1)
    except FileNotFoundError:
        token = secrets.token_urlsafe(24)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "w") as f:
                f.write(token + "\n")
        except FileExistsError:        # another station made it meanwhile: that one is the token
            return load_token(path)
        except OSError as e:
            raise TokenError(f"token file {path} cannot be written ({e.strerror})") from None
        return token, True
    except OSError as e:
        raise TokenError(f"token file {path} cannot be read ({e.strerror})") from None
    if len(raw) > MAX_TOKEN_FILE_BYTES:
        raise TokenError(f"token file {path} is larger than {MAX_TOKEN_FILE_BYTES} bytes")
    try:
        token = raw.decode("ascii").strip()
    except UnicodeDecodeError:
        raise TokenError(f"token file {path} is not ASCII text") from None
    problem = token_problem(token)
    if problem:
        raise TokenError(f"token file {path}: {problem}")
    return token, False


def token_problem(token: str) -> str | None:
    """Why a token (from a file) cannot be used, or None; never quotes it."""
    if len(token) < MIN_TOKEN_CHARS:
        return f"the token needs at least {MIN_TOKEN_CHARS} characters"
    if not set(token) <= TOKEN_CHARS:
        return "the token may hold only letters, digits and - _ . ~ (it is sent in the page's address)"
    return None


def _ip(name: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(name)
    except ValueError:
        return None


@dataclass(frozen=True)
class Access:
    bind: str
    port: int                      # the port served (the real one when 0 was asked for)
    token: str
    names: tuple[str, ...] = ()    # the caregiver's names for this station (e.g. robot-pc.local)

    def allowed(self, name: str) -> bool:
        """Whether a Host's name (lower case, IPv6 without brackets) is this station's."""
        ip = _ip(name)
        if name in LOOPBACK or name in (n.lower().strip("[]") for n in self.names):
            return True
        if ip is not None:
            bind = _ip(self.bind)
            return ip.is_loopback or self.bind in WILDCARD or (bind is not None and ip == bind)
        return name == self.bind.lower()

    def host_refusal(self, host: str | None) -> str | None:
        """Why a request's Host is not this station, or None. Never quotes the Host (a peer's text)."""
        if not host:
            return "missing Host"
        try:
            u = urlsplit("//" + host)
            name, port = (u.hostname or ""), (u.port if u.port is not None else 80)
        except ValueError:
            return "a Host that is not a name and port"
        if u.username is not None or u.password is not None or u.path or u.query or u.fragment:
            return "a Host that is not a name and port"
        if not self.allowed(name) or port != self.port:
            return ("this station is not served under that name: open the address it printed at its "
                    "start (another name needs the station's hosts parameter)")
        return None

    def page_refusal(self, host: str | None, given_token: str) -> str | None:
        """Why a request for the page or one of its files is refused, or None."""
        return self.host_refusal(host) or token_refusal(self.token, given_token)

    def handshake_refusal(self, host: str | None, origin: str | None, given_token: str) -> str | None:
        """Why a WebSocket upgrade is refused, or None: the Host is this station, the page that opens
        the socket came from it (Origin equals Host), and the token."""
        refusal = self.host_refusal(host)
        if refusal:
            return refusal
        if not origin:
            return "missing Origin"
        o = urlsplit(origin)
        if o.scheme not in ("http", "https") or o.netloc.lower() != host.lower():
            return "the page that opened this socket is not this station's"
        if not self.token:
            return "the station has no token"
        return token_refusal(self.token, given_token)


def token_refusal(token: str, given_token: str) -> str | None:
    """Why a request with ``given_token`` is refused, or None; compared in constant time. No token
    configured: refused (the station always has one)."""
    if not token or not hmac.compare_digest(token.encode(), given_token.encode()):
        return "wrong or missing token: open the address the station printed at its start"
    return None
