"""Who may open the station (issue 32, item 6): the Host must name this station (DNS rebinding), the
socket's Origin must be the station, and the token is needed on every address, loopback included.
Unit tests of access.py, then the same through the running server (GET /, a file, the handshake), and
a half-open request that is closed."""
import os
import socket
import stat

import pytest
from vla_operator.access import Access, TokenError, load_token, token_refusal
from vla_operator.server import Limits, Station

TOKEN = "s3cret-token-0123456789"
LOCAL = Access("127.0.0.1", 8080, TOKEN)
EVERYWHERE = Access("0.0.0.0", 8080, TOKEN, names=("robot-pc.local",))


@pytest.mark.parametrize("access, host", [
    (LOCAL, "127.0.0.1:8080"), (LOCAL, "localhost:8080"), (LOCAL, "LOCALHOST:8080"), (LOCAL, "[::1]:8080"),
    (EVERYWHERE, "10.0.0.2:8080"), (EVERYWHERE, "robot-pc.local:8080"), (EVERYWHERE, "[fe80::1]:8080"),
    (Access("10.0.0.2", 80, TOKEN), "10.0.0.2"),
])
def test_hosts_that_name_the_station(access, host):
    assert access.host_refusal(host) is None


@pytest.mark.parametrize("access, host", [
    (LOCAL, "evil.example:8080"),            # a rebinding site's own name (its DNS now says 127.0.0.1)
    (LOCAL, "127.0.0.1.evil.example:8080"), (LOCAL, "localhost.:8080"), (LOCAL, "127.0.0.1:8081"),
    (LOCAL, "127.0.0.1"), (LOCAL, "10.0.0.2:8080"), (LOCAL, "user@127.0.0.1:8080"),
    (LOCAL, "127.0.0.1:8080/x"), (LOCAL, "127.0.0.1:99999"), (LOCAL, "[::1"), (LOCAL, ""), (LOCAL, None),
    (EVERYWHERE, "robot-pc:8080"), (EVERYWHERE, "evil.example:8080"),
])
def test_hosts_that_do_not(access, host):
    refusal = access.host_refusal(host)
    assert refusal and (host is None or not host or host.split(":")[0] not in refusal)


def test_the_handshake_needs_this_stations_origin_and_the_token():
    ok = dict(host="127.0.0.1:8080", origin="http://127.0.0.1:8080", given_token=TOKEN)
    assert LOCAL.handshake_refusal(**ok) is None
    named = {**ok, "host": "localhost:8080", "origin": "http://localhost:8080"}
    assert LOCAL.handshake_refusal(**named) is None
    # a rebinding page sends its own name in both Origin and Host: Origin equals Host proves nothing
    assert "not served under that name" in LOCAL.handshake_refusal(
        **{**ok, "host": "evil.example:8080", "origin": "http://evil.example:8080"})
    assert "not this station's" in LOCAL.handshake_refusal(**{**ok, "origin": "http://evil.example"})
    assert "missing Origin" in LOCAL.handshake_refusal(**{**ok, "origin": None})
    for given in ("", "guess", TOKEN[:-1], TOKEN + "x"):
        assert "wrong or missing token" in LOCAL.handshake_refusal(**{**ok, "given_token": given})
    assert "no token" in Access("127.0.0.1", 8080, "").handshake_refusal(**ok)


def test_the_token_is_compared_and_never_optional():
    assert token_refusal(TOKEN, TOKEN) is None
    assert "wrong or missing token" in token_refusal(TOKEN, "")
    assert "wrong or missing token" in token_refusal("", "")          # a station without one refuses


def test_a_missing_token_file_is_made_for_its_owner_only_and_kept(tmp_path):
    path = tmp_path / "cfg" / "token"
    token, made = load_token(path)
    assert made and len(token) >= 16 and stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert load_token(path) == (token, False)                        # a restart keeps the address


@pytest.mark.parametrize("content, words", [
    (b"short\n", "at least 16 characters"), (b"<secret> with spaces and more", "may hold only"),
    (b"\xff\xfe" * 20, "not ASCII"), (b"x" * 5000, "larger than"),
])
def test_a_token_file_that_cannot_be_used_is_refused_without_quoting_it(tmp_path, content, words):
    path = tmp_path / "token"
    path.write_bytes(content)
    with pytest.raises(TokenError) as e:
        load_token(path)
    assert words in str(e.value) and "secret" not in str(e.value) and "short" not in str(e.value)


# ---------------------------------------------------------------------- through the server
@pytest.fixture
def served(tmp_path):
    web = tmp_path / "web"
    web.mkdir()
    (web / "index.html").write_text("<!doctype html><title>station</title>")
    (web / "app.js").write_text("// the page")
    station = Station(web, "127.0.0.1", 0, TOKEN, lambda axis: None, lambda msg, reply: None,
                      limits=Limits(request_timeout=0.5))
    station.start()
    yield station
    station.stop()


def http(station: Station, path: str, host: str) -> tuple[int, bytes]:
    """One raw HTTP/1.1 request with the Host given (a browser's, after a rebinding)."""
    with socket.create_connection(("127.0.0.1", station.access.port), timeout=30) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


def test_a_foreign_host_gets_neither_the_page_nor_a_file_nor_the_socket(served, page_class):
    """Issue 32: a page on a site whose name rebinds to 127.0.0.1 was accepted as the driver."""
    port = served.access.port
    here, evil = f"127.0.0.1:{port}", f"evil.example:{port}"
    assert http(served, f"/?token={TOKEN}", here)[0] == 200
    assert http(served, "/static/app.js", here)[0] == 200
    for path in (f"/?token={TOKEN}", "/static/app.js", "/static/nothing.js", f"/ws?token={TOKEN}"):
        code, body = http(served, path, evil)
        assert code == 403 and b"not served under that name" in body and b"evil" not in body, path
    import websocket
    with pytest.raises(websocket.WebSocketBadStatusException) as e:
        page_class(f"http://127.0.0.1:{port}/?token={TOKEN}", host=evil, origin=f"http://{evil}")
    assert e.value.status_code == 403
    page = page_class(f"http://127.0.0.1:{port}/?token={TOKEN}")
    try:
        assert page.wait(lambda p: p.of("hello"))
    finally:
        page.close()


def test_loopback_needs_the_token_too(served, page_class):
    port = served.access.port
    assert http(served, "/", f"127.0.0.1:{port}")[0] == 403
    import websocket
    with pytest.raises(websocket.WebSocketBadStatusException):
        page_class(f"http://127.0.0.1:{port}/")


def test_a_half_open_request_is_closed(served):
    """Issue 32: a request whose headers never end held its connection for good."""
    with socket.create_connection(("127.0.0.1", served.access.port), timeout=30) as s:
        s.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        assert s.recv(1) == b""          # closed by the station (after request_timeout; 30 s: a hang)
