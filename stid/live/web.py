"""The live view as a local web page: ``http://127.0.0.1:PORT/``.

The standard library's HTTP server, on the loopback interface only (nothing leaves the
machine). The page (``page.html``: one file, no external assets) follows the updates
through server-sent events (``/events``), or by polling ``/state`` where those are not
available, and redraws without a reload. It tells the server which update it shows
(``POST /ack``, read back at ``/viewers``): whether a page keeps up can be seen, and a
test can check what a real browser drew. A page that follows the events is listed there
while its stream is open: a closed page is forgotten at the next update or keep-alive.
"""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

PAGE = Path(__file__).with_name("page.html")
KEEPALIVE_S = 10.0


class LiveServer:
    def __init__(self, port: int = 0, host: str = "127.0.0.1"):
        self._cond = threading.Condition()
        self._doc: dict = {"seq": 0, "state": ["waiting for the first update"], "params": [], "history": []}
        self._closing = False
        self.acks: dict = {}  # view id -> the last thing it said it shows
        self._streams: dict = {}  # view id -> its open event streams (a page may reconnect)
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):  # the terminal belongs to the live table
                pass

            def do_GET(self):
                path = self.path.split("?", 1)[0]
                if path == "/":
                    self._send(200, "text/html; charset=utf-8", PAGE.read_bytes())
                elif path == "/state":
                    self._send(200, "application/json", server._encoded())
                elif path == "/events":
                    query = parse_qs(urlsplit(self.path).query)
                    server._stream(self, (query.get("view") or [None])[0])
                elif path == "/viewers":  # what each open page says it shows
                    with server._cond:
                        body = json.dumps(server.acks).encode()
                    self._send(200, "application/json", body)
                else:
                    self._send(404, "text/plain", b"not found: the live view is at /")

            def do_POST(self):
                if self.path != "/ack":
                    self._send(404, "text/plain", b"not found")
                    return
                n = int(self.headers.get("Content-Length") or 0)
                try:
                    doc = json.loads(self.rfile.read(min(n, 65536)) or b"{}")
                except json.JSONDecodeError:
                    self._send(400, "text/plain", b"not JSON")
                    return
                if isinstance(doc, dict) and doc.get("view"):
                    with server._cond:
                        server.acks[str(doc["view"])] = {**doc, "received": time.time()}
                self._send(204, "text/plain", b"")

            def _send(self, code, ctype, body: bytes):
                self.send_response(code)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                if body:
                    self.wfile.write(body)

        try:
            self.httpd = ThreadingHTTPServer((host, port), Handler)
        except OSError as e:  # (the port in use: "Address already in use" named no port)
            from stid.errors import InputError

            raise InputError(f"--web {port}: cannot serve the live view on {host}:{port} ({e.strerror or e}): "
                             "another program may hold it; give another port, or --web alone for a free one") from None
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        self.url = f"http://{host}:{self.port}/"
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="stid-live-web", daemon=True)
        self._thread.start()

    def publish(self, doc: dict) -> None:
        with self._cond:
            self._doc = doc
            self._cond.notify_all()

    def _encoded(self) -> bytes:
        with self._cond:
            return json.dumps(self._doc, allow_nan=False).encode()

    def _stream(self, h: BaseHTTPRequestHandler, view: str | None = None) -> None:
        """Server-sent events: the current state at once, then every new one. ``view``: the
        page's id; once its last stream ends (the page was closed) it leaves ``/viewers``."""
        if view:
            with self._cond:
                self._streams[view] = self._streams.get(view, 0) + 1
        try:
            self._send_events(h)
        finally:
            if view:
                with self._cond:
                    self._streams[view] -= 1
                    if not self._streams[view]:
                        del self._streams[view]
                        self.acks.pop(view, None)

    def _send_events(self, h: BaseHTTPRequestHandler) -> None:
        h.send_response(200)
        h.send_header("Content-Type", "text/event-stream")
        h.send_header("Cache-Control", "no-store")
        h.send_header("Connection", "keep-alive")
        h.end_headers()
        seen = -1
        try:
            while not self._closing:
                with self._cond:
                    if self._doc.get("seq", 0) == seen:
                        self._cond.wait(KEEPALIVE_S)
                    doc, fresh = self._doc, self._doc.get("seq", 0) != seen
                if self._closing:
                    break
                if fresh:
                    seen = doc.get("seq", 0)
                    body = json.dumps(doc, allow_nan=False)
                    h.wfile.write(f"id: {seen}\ndata: {body}\n\n".encode())
                else:
                    h.wfile.write(b": keepalive\n\n")
                h.wfile.flush()
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass  # the page was closed
        h.close_connection = True

    def close(self) -> None:
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self.httpd.shutdown()
        self.httpd.server_close()
