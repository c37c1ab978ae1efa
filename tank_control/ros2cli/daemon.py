"""``ros2 daemon start|stop|status`` and the daemon itself: a background process that keeps
a DDS participant, so the graph is already known when a command asks.

A command such as ``ros2 param get`` otherwise starts rclpy, joins the graph and waits for
discovery (0.5–3.5 s). With the daemon it sends its arguments over a local socket; the
daemon runs the same verb with a node of its long-lived participant and returns the
output. One daemon per ``ROS_DOMAIN_ID`` and discovery settings (:func:`daemon_key`):
the socket is ``ros2-daemon-d<domain>-<key>.sock`` in ``$XDG_RUNTIME_DIR`` (else in a
private ``/tmp/tank_control-<uid>``), mode 0600; a connection from another user is
refused (``SO_PEERCRED``). Started on demand by the first command that can use it,
stopped by ``ros2 daemon stop``, SIGTERM/SIGINT, or after ``idle_timeout`` s without a
request. When it cannot start, commands discover the graph themselves.

Protocol: one JSON object per line each way. Requests: ``{"op": "ping"}``,
``{"op": "stop"}``, ``{"op": "run", "argv": [...]}`` (only the verbs of
:data:`DAEMON_VERBS`); answers: ``{"ok": true, ...}`` or ``{"ok": false, "error": ...}``.
A request longer than :data:`MAX_REQUEST` bytes, slower than :data:`READ_TIMEOUT` s, not
JSON or of another shape gets an error answer and changes nothing.
"""
from __future__ import annotations

import argparse
import fcntl
import hashlib
import io
import json
import os
import signal
import socket
import stat
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tank_control.ros2cli.common import CliError

#: Verbs the daemon runs (``ros2 <command> <verb>``): answers that do not depend on the
#: caller's directory, terminal or input.
DAEMON_VERBS = frozenset({('param', 'list'), ('param', 'get'), ('param', 'set'),
                          ('param', 'describe'), ('param', 'dump'), ('node', 'list'),
                          ('node', 'info'), ('topic', 'list'), ('service', 'list')})
#: Environment that selects a graph: a daemon serves only commands with the same values.
DISCOVERY_ENV = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS',
                 'ROS_LOCALHOST_ONLY', 'RMW_IMPLEMENTATION', 'FASTRTPS_DEFAULT_PROFILES_FILE',
                 'FASTDDS_DEFAULT_PROFILES_FILE', 'ROS_DISCOVERY_SERVER',
                 'ROS_SUPER_CLIENT', 'CYCLONEDDS_URI')
#: Commands use the daemon unless this is set to 1 (or ``--no-daemon`` is given).
NO_DAEMON_ENV = 'TANK_CONTROL_ROS2_NO_DAEMON'
#: Seconds without a request after which a daemon started on demand ends (default 2 h).
IDLE_ENV = 'TANK_CONTROL_ROS2_DAEMON_IDLE'
IDLE_TIMEOUT = 7200.0
MAX_REQUEST = 64 * 1024     # [bytes] longest request line
MAX_ARGS = 64               # most arguments of a forwarded command
READ_TIMEOUT = 5.0          # [s] to receive a whole request once connected
MAX_CLIENTS = 16            # requests served at once; more get "busy"
START_WAIT = 20.0           # [s] for a daemon started on demand to listen


# ------------------------------------------------------------------------------- addresses

def daemon_key(env: Mapping[str, str]) -> str:
    """8 hex digits naming the discovery settings, the network namespace (a unix socket is
    reachable from every one) and this checkout's code."""
    import tank_control
    text = '\n'.join(f'{k}={env.get(k, "")}' for k in DISCOVERY_ENV)
    text += '\n' + os.path.dirname(os.path.abspath(tank_control.__file__))
    try:
        text += '\n' + os.readlink('/proc/self/ns/net')
    except OSError:
        pass
    return hashlib.sha256(text.encode()).hexdigest()[:8]


def domain_of(env: Mapping[str, str]) -> str:
    domain = env.get('ROS_DOMAIN_ID', '').strip() or '0'
    return domain if domain.isdigit() else 'x'


def socket_dir(env: Mapping[str, str] | None = None) -> Path:
    """``$XDG_RUNTIME_DIR`` when it is ours and private, else ``/tmp/tank_control-<uid>``
    (created 0700; refused if someone else owns it or others may write to it)."""
    env = os.environ if env is None else env
    runtime = env.get('XDG_RUNTIME_DIR', '')
    if runtime and _private_dir(Path(runtime)):
        return Path(runtime)
    path = Path('/tmp') / f'tank_control-{os.getuid()}'
    try:
        path.mkdir(mode=0o700)
    except FileExistsError:
        pass
    if not _private_dir(path):
        raise CliError(f'{path}: not a private directory of this user; the ros2 daemon '
                       'does not use it')
    return path


def _private_dir(path: Path) -> bool:
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return (stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and
            not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH))


def socket_path(env: Mapping[str, str] | None = None) -> Path:
    env = os.environ if env is None else env
    return socket_dir(env) / f'ros2-daemon-d{domain_of(env)}-{daemon_key(env)}.sock'


def sockets_of_domain(domain: str, env: Mapping[str, str] | None = None) -> list[Path]:
    """Every daemon socket of ``domain`` (any discovery settings)."""
    return sorted(socket_dir(env).glob(f'ros2-daemon-d{domain}-*.sock'))


# ---------------------------------------------------------------------------------- client

def _connect(path: Path, timeout: float) -> socket.socket | None:
    """A connection to the daemon at ``path``; None when none listens there. A socket
    file not owned by this user, or readable by others, is never used."""
    try:
        st = os.lstat(path)
    except OSError:
        return None
    if not stat.S_ISSOCK(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise CliError(f'{path}: not a private socket of this user; the ros2 daemon does '
                       'not use it (remove it)')
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.settimeout(timeout)
    try:
        sock.connect(str(path))
    except OSError:
        sock.close()
        return None
    return sock


def _exchange(sock: socket.socket, request: Mapping[str, Any], timeout: float) -> dict:
    """Send one request line and read the answer line (within ``timeout`` s)."""
    with sock:
        sock.settimeout(timeout)
        sock.sendall(json.dumps(request).encode() + b'\n')
        data = bytearray()
        deadline = time.monotonic() + timeout
        while not data.endswith(b'\n'):
            sock.settimeout(max(0.01, deadline - time.monotonic()))
            chunk = sock.recv(65536)
            if not chunk:
                raise ConnectionError('the daemon closed the connection')
            data += chunk
    answer = json.loads(data)
    if not isinstance(answer, dict):
        raise ConnectionError('the daemon answered something else than an object')
    return answer


def request(op: str, env: Mapping[str, str] | None = None, path: Path | None = None,
            timeout: float = 5.0, **fields: Any) -> dict | None:
    """One request to the running daemon; None when no daemon listens."""
    path = socket_path(env) if path is None else path
    sock = _connect(path, timeout)
    if sock is None:
        return None
    return _exchange(sock, {'op': op, **fields}, timeout)


def start(env: Mapping[str, str] | None = None, idle_timeout: float | None = None,
          wait: float = START_WAIT) -> dict | None:
    """Start the daemon (if none runs) and wait until it answers; its status, or None
    when it could not start within ``wait`` s."""
    env = dict(os.environ if env is None else env)
    path = socket_path(env)
    status = _ping(path)
    if status is not None:
        return status
    if idle_timeout is None:
        try:
            idle_timeout = float(env.get(IDLE_ENV, IDLE_TIMEOUT))
        except ValueError:
            idle_timeout = IDLE_TIMEOUT
    log = path.with_suffix('.log')
    with open(log, 'ab') as err:
        os.chmod(log, 0o600)
        process = subprocess.Popen(
            [sys.executable, '-m', 'tank_control.ros2cli.daemon', str(path),
             '--idle-timeout', repr(idle_timeout)],
            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err,
            start_new_session=True, close_fds=True, cwd='/')
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        status = _ping(path)
        if status is not None:
            return status
        if process.poll() not in (None, 0):
            return None        # it failed (its log says why); exit 0: another one is starting
        time.sleep(0.05)       # polling the socket: the daemon has no other way to say "ready"
    return None


def _ping(path: Path) -> dict | None:
    try:
        answer = request('ping', path=path, timeout=2.0)
    except (OSError, ValueError, ConnectionError):
        return None
    return answer if answer and answer.get('ok') else None


def stop(path: Path, wait: float = 10.0) -> bool:
    """Ask the daemon at ``path`` to end; True once it is gone (False: none was running)."""
    try:
        answer = request('stop', path=path, timeout=wait)
    except (OSError, ValueError, ConnectionError):
        answer = None
    if answer is None:
        return False
    deadline = time.monotonic() + wait
    while path.exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    pid = answer.get('pid')
    while isinstance(pid, int) and _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.02)
    return True


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:   # a zombie (our own child, not yet reaped) has ended
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def stop_domain(domain: str, env: Mapping[str, str] | None = None) -> int:
    """Stop every daemon of ``domain`` (test sessions end with this); how many were. The
    socket of a daemon that was killed (nobody listens on it) is removed."""
    stopped = 0
    for path in sockets_of_domain(domain, env):
        if stop(path):
            stopped += 1
            continue
        try:
            sock = _connect(path, 1.0)
        except CliError:
            continue              # not ours to remove
        if sock is None:
            path.unlink(missing_ok=True)
        else:
            sock.close()
    return stopped


def wanted(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> bool:
    """Whether this parsed command goes through the daemon."""
    env = os.environ if env is None else env
    return (getattr(args, 'daemon_verb', False) and not getattr(args, 'no_daemon', False)
            and env.get(NO_DAEMON_ENV, '') not in ('1', 'true', 'yes'))


def forward(argv: Sequence[str], wait: float, read_only: bool) -> int | None:
    """Run ``ros2 ARGV`` in the daemon (started on demand) and print its output; its exit
    code, or None when there is no daemon to use (the caller then discovers itself).

    ``wait`` [s]: longest wait for the answer. A command with effects (``read_only``
    False) that was sent but got no answer is not run again (it may have been applied):
    that ends in an error instead.
    """
    try:
        path = socket_path()
        sock = _connect(path, 2.0)
        if sock is None:
            if start() is None:
                return None
            sock = _connect(path, 2.0)
            if sock is None:
                return None
    except (CliError, OSError):
        return None
    try:
        answer = _exchange(sock, {'op': 'run', 'argv': list(argv)}, wait)
    except (OSError, ValueError, ConnectionError) as exc:
        if read_only:
            return None
        raise CliError(f'the ros2 daemon did not answer ({exc}); the change may or may not '
                       'have been applied: check with `ros2 param get`') from None
    if not answer.get('ok'):
        if read_only:
            return None
        raise CliError(f"the ros2 daemon refused the command: {answer.get('error')}")
    sys.stdout.write(str(answer.get('stdout', '')))
    sys.stdout.flush()
    sys.stderr.write(str(answer.get('stderr', '')))
    rc = answer.get('rc', 1)
    return rc if isinstance(rc, int) else 1


# ---------------------------------------------------------------------------------- server

class _Router(io.TextIOBase):
    """``sys.stdout``/``sys.stderr`` of the daemon: each request thread writes into its
    own buffer; other threads into the original stream."""

    def __init__(self, original: Any, local: threading.local, which: str) -> None:
        self._original, self._local, self._which = original, local, which

    def write(self, text: str) -> int:
        buffer = getattr(self._local, self._which, None)
        return (buffer if buffer is not None else self._original).write(text)

    def flush(self) -> None:
        if getattr(self._local, self._which, None) is None:
            self._original.flush()

    def writable(self) -> bool:
        return True


class Daemon:
    """The daemon process: one participant, one node watching the graph, a unix socket."""

    def __init__(self, path: Path, idle_timeout: float) -> None:
        self.path = path
        self.idle_timeout = idle_timeout
        self.started = time.monotonic()
        self.last_request = self.started
        self.active = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self._local = threading.local()
        self._snapshot: tuple = ()
        self._changed = self.started
        self._counter = 0
        self.context: Any = None
        self.node: Any = None

    # graph clock used by common.settle_graph -----------------------------------------
    def graph_changed(self) -> float:
        """Monotonic time of the last change of the graph seen by this participant."""
        from tank_control.ros2cli.common import graph_snapshot
        snapshot = graph_snapshot(self.node)
        with self._lock:
            if snapshot != self._snapshot:
                self._snapshot, self._changed = snapshot, time.monotonic()
            return self._changed

    def node_name(self) -> str:
        with self._lock:
            self._counter += 1
            return f'_ros2cli_daemon_{os.getpid()}_{self._counter}'

    # ------------------------------------------------------------------------------
    def serve(self) -> int:
        lock_file = open(self.path.with_suffix('.lock'), 'a')
        os.chmod(lock_file.name, 0o600)
        try:
            fcntl.flock(lock_file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return 0          # another daemon serves this address
        import rclpy
        from rclpy.signals import SignalHandlerOptions

        from tank_control.ros2cli import common
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        self.context = rclpy.get_default_context()
        self.node = rclpy.create_node(f'_ros2cli_daemon_{os.getpid()}', enable_rosout=False,
                                      start_parameter_services=False,
                                      use_global_arguments=False)
        self.graph_changed()
        common.DAEMON = self
        sys.stdout = _Router(sys.stdout, self._local, 'stdout')
        sys.stderr = _Router(sys.stderr, self._local, 'stderr')
        for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            signal.signal(sig, lambda *_: self._stop.set())
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            if self.path.exists() or self.path.is_symlink():
                self.path.unlink()       # stale: its daemon no longer holds the lock
            old_umask = os.umask(0o177)
            try:
                server.bind(str(self.path))
            finally:
                os.umask(old_umask)
            os.chmod(self.path, 0o600)
            server.listen(MAX_CLIENTS)
            server.settimeout(0.1)
            with self._lock:
                self.last_request = time.monotonic()     # idle from now on, not from start-up
            while not self._stop.is_set():
                self.graph_changed()
                with self._lock:
                    idle = self.active == 0 and \
                        time.monotonic() - self.last_request > self.idle_timeout
                if idle:
                    break
                try:
                    conn, _ = server.accept()
                except TimeoutError:
                    continue
                except OSError:
                    if self._stop.is_set():
                        break
                    raise
                threading.Thread(target=self._handle, args=(conn,), daemon=True).start()
        finally:
            try:
                self.path.unlink()
            except OSError:
                pass
            server.close()
            deadline = time.monotonic() + 5.0
            while self.active and time.monotonic() < deadline:
                time.sleep(0.02)
            common.DAEMON = None
            self.node.destroy_node()
            rclpy.try_shutdown()
            lock_file.close()
        return 0

    def _handle(self, conn: socket.socket) -> None:
        with conn:
            try:
                creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                        struct.calcsize('3i'))
                _, uid, _ = struct.unpack('3i', creds)
                if uid != os.getuid():
                    return
                if not self._slots.acquire(blocking=False):
                    self._send(conn, {'ok': False, 'error': 'busy'})
                    return
                try:
                    with self._lock:
                        self.active += 1
                    try:
                        self._send(conn, self._answer(self._receive(conn)))
                    finally:
                        with self._lock:
                            self.active -= 1
                            self.last_request = time.monotonic()
                finally:
                    self._slots.release()
            except (OSError, ValueError):
                return       # the client went away
            except Exception as exc:   # never ends the daemon; the client falls back
                print(f'ros2 daemon: request failed: {type(exc).__name__}: {exc}',
                      file=sys.__stderr__)

    @staticmethod
    def _send(conn: socket.socket, answer: Mapping[str, Any]) -> None:
        conn.settimeout(READ_TIMEOUT)
        conn.sendall(json.dumps(answer).encode() + b'\n')

    def _receive(self, conn: socket.socket) -> Any:
        conn.settimeout(READ_TIMEOUT)
        deadline = time.monotonic() + READ_TIMEOUT
        data = bytearray()
        while b'\n' not in data:
            if len(data) > MAX_REQUEST:
                return ValueError(f'request longer than {MAX_REQUEST} bytes')
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return ValueError(f'request not complete within {READ_TIMEOUT:g} s')
            conn.settimeout(remaining)
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                continue
            if not chunk:
                return ValueError('connection closed before the end of the request')
            data += chunk
        line = bytes(data.split(b'\n', 1)[0])
        if len(line) > MAX_REQUEST:
            return ValueError(f'request longer than {MAX_REQUEST} bytes')
        try:
            return json.loads(line.decode('utf-8'))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            return ValueError(f'request is not JSON: {exc}')

    def _answer(self, req: Any) -> dict:
        if isinstance(req, ValueError):
            return {'ok': False, 'error': str(req)}
        if not isinstance(req, dict) or not isinstance(req.get('op'), str):
            return {'ok': False, 'error': 'a request is an object with "op"'}
        op = req['op']
        if op == 'ping':
            return {'ok': True, 'pid': os.getpid(), 'domain': domain_of(os.environ),
                    'age': round(time.monotonic() - self.started, 3), 'socket': str(self.path),
                    'idle_timeout': self.idle_timeout}
        if op == 'stop':
            self._stop.set()
            return {'ok': True, 'pid': os.getpid()}
        if op == 'run':
            argv = req.get('argv')
            if not (isinstance(argv, list) and 2 <= len(argv) <= MAX_ARGS and
                    all(isinstance(a, str) and len(a) <= 4096 and '\0' not in a
                        for a in argv)):
                return {'ok': False, 'error': f'"argv" is a list of 2 to {MAX_ARGS} strings'}
            if (argv[0], argv[1]) not in DAEMON_VERBS:
                return {'ok': False, 'error': f'not served by the daemon: {argv[0]} {argv[1]}'}
            return self._run(argv)
        return {'ok': False, 'error': f'unknown op {op[:40]!r}; known: ping, stop, run'}

    def _run(self, argv: list[str]) -> dict:
        from tank_control.ros2cli import main
        out, err = io.StringIO(), io.StringIO()
        self._local.stdout, self._local.stderr = out, err
        try:
            rc = main.run_cli(argv)
        except SystemExit as exc:    # argparse refused the arguments (message on stderr)
            rc = exc.code if isinstance(exc.code, int) else 2
        finally:
            self._local.stdout = self._local.stderr = None
        return {'ok': True, 'rc': rc, 'stdout': out.getvalue(), 'stderr': err.getvalue()}


# ------------------------------------------------------------------------------------ verb

def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        'daemon', help='Various daemon related sub-commands',
        description='The ros2 daemon keeps a participant in the graph so that commands '
                    'answer without discovering it again. It starts on demand; one runs per '
                    'ROS_DOMAIN_ID and discovery settings.')
    verbs = parser.add_subparsers(title='Commands', dest='verb', metavar='VERB')
    verbs.required = True
    p = verbs.add_parser('start', help='Start the daemon if it is not running')
    p.add_argument('--idle-timeout', type=float, default=None, metavar='SECONDS',
                   help=f'end after this many seconds without a request (default: '
                        f'${IDLE_ENV} or {IDLE_TIMEOUT:g})')
    p.set_defaults(func=start_verb)
    p = verbs.add_parser('stop', help='Stop the daemon if it is running')
    p.set_defaults(func=stop_verb)
    p = verbs.add_parser('status', help='Output the status of the daemon')
    p.set_defaults(func=status_verb)


def start_verb(args: argparse.Namespace) -> int:
    path = socket_path()
    if _ping(path) is not None:
        print('The daemon is already running')
        return 0
    status = start(idle_timeout=args.idle_timeout)
    if status is None:
        raise CliError(f'The daemon did not start within {START_WAIT:g} s (log: '
                       f'{path.with_suffix(".log")})')
    print(f"The daemon has been started (pid {status['pid']}, domain {status['domain']})")
    return 0


def stop_verb(args: argparse.Namespace) -> int:
    print('The daemon has been stopped' if stop(socket_path()) else 'The daemon is not running')
    return 0


def status_verb(args: argparse.Namespace) -> int:
    path = socket_path()
    status = _ping(path)
    if status is None:
        print('The daemon is not running')
        return 0
    print(f"The daemon is running (pid {status['pid']}, domain {status['domain']}, "
          f"socket {path}, up {status['age']:.0f} s)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m tank_control.ros2cli.daemon',
                                     description='Serve ros2 commands on a unix socket.')
    parser.add_argument('socket', type=Path)
    parser.add_argument('--idle-timeout', type=float, default=IDLE_TIMEOUT)
    args = parser.parse_args(argv)
    return Daemon(args.socket, args.idle_timeout).serve()


if __name__ == '__main__':
    sys.exit(main())
