"""The dashboard's web server: the page, its assets and one WebSocket per page (aiohttp).

Runs its own asyncio loop in a thread beside the node's executor and touches no rclpy object:
samples come from the :class:`~tank_control.dashboard.store.SampleStore`, the graph's state
from ``Backend.snapshot()``, and a page's requests (set a parameter, call a command) go to
``Backend.request`` with a reply function that may be called from any thread.

WebSocket messages (JSON objects, ``type`` says which): to the page ``hello`` (the snapshot),
``samples`` (every ``update_period``: the rows since the last batch, store.py), and the
backend's events (``node``, ``node_gone``, ``param``, ``state``, ``limits``, ``origin``,
``set_result``, ``command_result``); from the page ``set`` (``node``, ``name``, ``text``,
``id``, ``token``) and ``command`` (``node``, ``command``, ``id``, ``token``): a write without
this start's token, or any write when read-only, is answered as refused by the server itself
(dashboard/access.py), as is every request (HTTP 403) of a foreign Host or Origin. The backend's ``robustness`` event
(dashboard/robustness.py) is also part of the snapshot.

The runs page (``/runs``, dashboard/runs.py): ``/api/runs`` lists the run folders under
``runs_dir`` as JSON, ``/runs/file/<run>/<file>`` serves a file of one (read-only, only from
inside ``runs_dir``).
"""
from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Protocol

from aiohttp import WSMsgType, web

from tank_control.dashboard.access import Access
from tank_control.dashboard.runs import list_runs, run_file
from tank_control.dashboard.store import SampleStore

#: Rows in one ``samples`` message at most (a page catching up gets several).
BATCH_LIMIT = 20_000
CONTENT_TYPES = {'.html': 'text/html', '.js': 'text/javascript', '.css': 'text/css',
                 '.txt': 'text/plain', '.svg': 'image/svg+xml', '.png': 'image/png',
                 '.json': 'application/json', '.csv': 'text/csv', '.yaml': 'text/plain'}
Reply = Callable[[dict[str, Any]], None]


class Backend(Protocol):
    """The ROS side as the server sees it (thread-safe)."""

    def snapshot(self) -> dict[str, Any]: ...

    def request(self, message: dict[str, Any], reply: Reply) -> None: ...


def load_assets() -> dict[str, tuple[bytes, str]]:
    """Every file of ``static/`` (package data) by URL path: ``(bytes, content type)``."""
    assets: dict[str, tuple[bytes, str]] = {}

    def walk(folder: Any, prefix: str) -> None:
        for entry in folder.iterdir():
            if entry.is_dir():
                walk(entry, f'{prefix}{entry.name}/')
            elif entry.is_file():
                suffix = '.' + entry.name.rsplit('.', 1)[-1]
                assets[f'{prefix}{entry.name}'] = (
                    entry.read_bytes(), CONTENT_TYPES.get(suffix, 'application/octet-stream'))

    walk(resources.files('tank_control.dashboard') / 'static', '/static/')
    assets['/'] = assets['/static/index.html']
    assets['/runs'] = assets['/static/runs.html']
    return assets


@dataclass(eq=False)
class _Client:
    ws: web.WebSocketResponse
    events: asyncio.Queue = field(default_factory=asyncio.Queue)


class DashboardServer:
    """The web server thread. ``start()`` binds (or raises ``OSError``) and returns the URL;
    ``broadcast`` hands an event to every page; ``stop()`` closes the pages and the thread."""

    def __init__(self, store: SampleStore, backend: Backend, host: str, port: int,
                 update_period: float, runs_dir: str = '',
                 access: Access | None = None) -> None:
        self.access = access if access is not None else Access(('self',), False, lambda _: None)
        self._store = store
        self._runs_dir = runs_dir
        self._backend = backend
        self._host = host
        self._port = port
        self._period = update_period
        self._assets = load_assets()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._clients: set[_Client] = set()
        self.url = ''

    # ---------------------------------------------------------------- thread control
    def start(self, timeout: float = 30.0) -> str:
        self._thread = threading.Thread(target=self._run, name='dashboard-web', daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise OSError(f'web server did not start within {timeout:g} s')
        if self._error is not None:
            raise OSError(f'cannot listen on {self._host}:{self._port}: '
                          f'{getattr(self._error, "strerror", None) or self._error}')
        return self.url

    def stop(self, timeout: float = 10.0) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(stop.set)
            except RuntimeError:       # the loop closed meanwhile
                pass
        if self._thread is not None:
            self._thread.join(timeout)

    def broadcast(self, event: dict[str, Any]) -> None:
        """Send ``event`` to every connected page (callable from any thread)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        text = json.dumps(event, allow_nan=False)
        try:
            loop.call_soon_threadsafe(self._queue_all, text)
        except RuntimeError:
            pass

    @property
    def client_count(self) -> int:
        return len(self._clients)

    def _queue_all(self, text: str) -> None:
        for client in self._clients:
            client.events.put_nowait(text)

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:        # noqa: B902 - reported by start()
            self._error = exc
        finally:
            self._ready.set()
            loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        app = web.Application(middlewares=[self._guard])
        app.router.add_get('/ws', self._websocket)
        app.router.add_get('/api/runs', self._runs)
        app.router.add_get('/runs/file/{path:.*}', self._run_file)
        app.router.add_get('/{path:.*}', self._asset)
        runner = web.AppRunner(app, handle_signals=False, access_log=None)
        await runner.setup()
        try:
            site = web.TCPSite(runner, self._host, self._port)
            await site.start()
            server = site._server                                  # noqa: SLF001
            sockets = server.sockets if isinstance(server, asyncio.Server) else ()
            port = sockets[0].getsockname()[1] if sockets else self._port
            host = f'[{self._host}]' if ':' in self._host else self._host
            self.url = f'http://{host}:{port}/'
            self._ready.set()
            await self._stop.wait()
            for client in list(self._clients):
                await client.ws.close(code=1001, message=b'dashboard stopping')
        finally:
            await runner.cleanup()

    # ---------------------------------------------------------------- handlers
    @web.middleware
    async def _guard(self, request: web.Request, handler: Any) -> web.StreamResponse:
        """Every request (the WebSocket's handshake too): a foreign Host or Origin gets 403
        with the one-line reason (dashboard/access.py)."""
        reason = self.access.http_reason(request.headers.get('Host'),
                                         request.headers.get('Origin'), request.scheme)
        if reason is not None:
            return web.Response(status=403, text=reason + '\n',
                                headers={'Cache-Control': 'no-store'})
        return await handler(request)

    async def _asset(self, request: web.Request) -> web.StreamResponse:
        found = self._assets.get(request.path)
        if found is None:
            raise web.HTTPNotFound()
        body, content_type = found
        return web.Response(body=body, content_type=content_type,
                            headers={'Cache-Control': 'no-cache'})

    async def _runs(self, request: web.Request) -> web.Response:
        table = await asyncio.get_running_loop().run_in_executor(None, list_runs,
                                                                 self._runs_dir)
        return web.json_response(table, dumps=lambda v: json.dumps(v, allow_nan=False),
                                 headers={'Cache-Control': 'no-cache'})

    async def _run_file(self, request: web.Request) -> web.StreamResponse:
        path = run_file(self._runs_dir, request.match_info['path'])
        if path is None:
            raise web.HTTPNotFound(text='no such file in runs_dir')
        body = await asyncio.get_running_loop().run_in_executor(None, path.read_bytes)
        kind = CONTENT_TYPES.get(path.suffix.lower(), 'application/octet-stream')
        return web.Response(body=body, content_type=kind,
                            headers={'Cache-Control': 'no-cache'})

    async def _websocket(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=1 << 20)
        await ws.prepare(request)
        client = _Client(ws)
        cursor = self._store.oldest_cursor()
        self._clients.add(client)
        writer = asyncio.ensure_future(self._write(client, cursor))
        try:
            async for msg in ws:
                if msg.type != WSMsgType.TEXT:
                    continue
                try:
                    message = json.loads(msg.data)
                except ValueError:
                    continue
                if not isinstance(message, dict):
                    continue
                reason = self.access.write_reason(message)
                if reason is None:
                    message['peer'] = request.remote or '?'
                    self._backend.request(message, self._reply_to(client))
                else:
                    self._refuse(client, message, reason)
        finally:
            self._clients.discard(client)
            writer.cancel()
            try:
                await writer
            except (asyncio.CancelledError, ConnectionError):
                pass
        return ws

    def _refuse(self, client: _Client, message: dict[str, Any], reason: str) -> None:
        """A write refused by ``access``: the page's usual answer, unsuccessful, the reason."""
        if message.get('type') == 'set':
            answer = {'type': 'set_result', 'node': message.get('node'),
                      'name': message.get('name'), 'successful': False, 'reason': reason}
        else:
            answer = {'type': 'command_result', 'node': message.get('node'),
                      'command': message.get('command'), 'success': False, 'message': reason}
        answer['id'] = message.get('id')
        try:
            client.events.put_nowait(json.dumps(answer, allow_nan=False, default=str))
        except ValueError:
            pass

    def _reply_to(self, client: _Client) -> Reply:
        loop = self._loop
        assert loop is not None, 'a client is served only while the server runs'

        def reply(event: dict[str, Any]) -> None:
            text = json.dumps(event, allow_nan=False)
            try:
                loop.call_soon_threadsafe(client.events.put_nowait, text)
            except RuntimeError:       # the server stopped meanwhile
                pass
        return reply

    async def _write(self, client: _Client, cursor: int) -> None:
        """The page's one writer: its events as they come, the samples every period."""
        ws, loop = client.ws, asyncio.get_running_loop()
        await ws.send_str(json.dumps({'type': 'hello', **self._backend.snapshot(),
                                      'read_only': self.access.read_only}, allow_nan=False))
        due = loop.time()
        while not ws.closed:
            wait = due - loop.time()
            if wait > 0:
                try:
                    text = await asyncio.wait_for(client.events.get(), wait)
                except asyncio.TimeoutError:
                    pass
                else:
                    await ws.send_str(text)
                    continue
            batch = self._store.since(cursor, BATCH_LIMIT)
            full = len(batch.rows) == BATCH_LIMIT
            due = loop.time() + (0.0 if full else self._period)
            if batch.rows or batch.lost:
                await ws.send_str(json.dumps(batch.as_message(), allow_nan=False))
            cursor = batch.cursor
