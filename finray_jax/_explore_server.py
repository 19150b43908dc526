"""The design explorer's local web server: a Bokeh server in this process, bound to the
loopback address, serving the page and BokehJS itself (no asset comes from the internet).

`serve` prepares the first design on the worker thread while the server already answers
(the page shows the preparation), prints the address, optionally opens a browser, and
runs until interrupted (Ctrl-C: KeyboardInterrupt, after the server stopped).
"""

from __future__ import annotations

import functools
import socket
import webbrowser

from bokeh.application import Application
from bokeh.application.handlers.function import FunctionHandler
from bokeh.server.server import Server
from bokeh.settings import settings

from ._explore_app import App
from ._explore_page import make_document

HOST = "127.0.0.1"
DEFAULT_PORT = 5006


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def start_server(app: App, port: int = DEFAULT_PORT) -> Server:
    """A started (not yet running) Bokeh server of the explorer's page at
    http://127.0.0.1:port/ (port 0: a free one)."""
    settings.resources.set_value("server")  # BokehJS from this server, never a CDN
    port = free_port() if port == 0 else port
    handler = FunctionHandler(functools.partial(make_document, app))
    server = Server(
        {"/": Application(handler)},
        address=HOST,
        port=port,
        allow_websocket_origin=[f"{HOST}:{port}", f"localhost:{port}"],
        num_procs=1,
    )
    server.start()
    return server


def address(server: Server) -> str:
    return f"http://{HOST}:{server.port}/"


def serve(app: App, port: int = DEFAULT_PORT, open_browser: bool = True, say=print) -> None:
    """Run the explorer until interrupted."""
    server = start_server(app, port)
    app.prepare()
    say(f"finray explore: {address(server)} (Ctrl-C stops it)")
    if open_browser:
        server.io_loop.add_callback(functools.partial(webbrowser.open, address(server)))
    try:
        server.io_loop.start()
    finally:
        server.stop()
