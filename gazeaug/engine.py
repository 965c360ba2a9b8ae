"""Where dataset work runs: on this machine (``local``, the default) or on a Ray cluster (``ray``).

The local engine is the one the commands always had (worker processes of this
machine, :mod:`gazeaug.jobs`). The Ray engine runs the same per-sample code in
*stateful actors* spread over a cluster:

- each actor builds its landmark detector and renderer once (MediaPipe is built
  inside the actor, never shared or forked; render scenes are built from plain
  arrays inside the actor) and runs OpenCV single-threaded;
- the driver cuts the work into *blocks* (contiguous sample ranges) and sends
  each block's sample descriptions, never images: the actor reads the images
  where the data is;
- results come back to the driver **in block order**, whatever the order the
  blocks finish in, so outputs are written in dataset order;
- an actor that dies (its process or its node lost) has its blocks sent again
  to the others, and a replacement actor is started where there is room; an
  error raised by the work itself (a bad dataset file) stops the run with that
  error, as locally.

Ray is an optional dependency (``pip install 'gazeaug[ray]'``).

Example (a local Ray instance with 2 actors):

    >>> from gazeaug.engine import Engine, map_blocks           # doctest: +SKIP
    >>> map_blocks(Engine("ray", workers=2), enumerate(blocks), work, setup, (), on_result=print)
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from .errors import GazeAugError

__all__ = [
    "Engine",
    "ENGINES",
    "WorkersLostError",
    "chunks",
    "import_ray",
    "check_address",
    "ray_session",
    "map_blocks",
    "node_name",
]

ENGINES = ("local", "ray")
_log = logging.getLogger(__name__)
INSTALL_HINT = "install it with: pip install 'gazeaug[ray]' (from a clone: pip install -e '.[ray]')"

#: Blocks in flight per actor: one being processed, one waiting (hides the driver's round trip).
_DEPTH = 2
#: How many times one block is sent again after the actor processing it was lost.
_MAX_ATTEMPTS = 4
#: How long a run waits with no actor running (starting ones included: MediaPipe and a scene take seconds).
_NO_WORKER_TIMEOUT_S = 300.0


class WorkersLostError(GazeAugError):
    """The cluster lost its workers (too often, or all of them for too long): the work done so far is resumable."""


@dataclass(frozen=True)
class Engine:
    """Where a dataset run goes.

    Attributes:
        kind: ``"local"`` (this machine's processes) or ``"ray"``.
        address: Ray only: ``HOST:PORT`` of a running cluster's head (``ray start --head``
            prints it); ``"auto"``: the cluster this machine is part of (``RAY_ADDRESS``, or the
            one ``ray start`` started here; what a job submitted with ``ray job submit`` uses);
            None starts a Ray instance on this machine for the run.
        workers: processes (local) or actors (Ray); None: 1 locally, every CPU of the cluster on Ray.
        block_size: Ray only: samples per block (the unit sent to an actor, written as one shard
            and retried as a whole; default 64).
    """

    kind: str = "local"
    address: str | None = None
    workers: int | None = None
    block_size: int = 64

    def __post_init__(self) -> None:
        if isinstance(self.address, str):
            object.__setattr__(self, "address", self.address.strip())
        if self.kind not in ENGINES:
            raise GazeAugError(f"engine: expected one of {ENGINES}, got {self.kind!r}")
        if self.address is not None and self.kind != "ray":
            raise GazeAugError("a Ray address is given, but the engine is not ray (add --engine ray)")
        if self.workers is not None and not (isinstance(self.workers, int) and self.workers >= 1):
            raise GazeAugError(f"workers: expected an integer >= 1, got {self.workers!r}")
        if not (isinstance(self.block_size, int) and self.block_size >= 1):
            raise GazeAugError(f"block size: expected an integer >= 1, got {self.block_size!r}")
        if self.address is not None and self.address != "auto":
            check_address_form(self.address)


def chunks(items: Iterable[Any], size: int) -> Iterator[list[Any]]:
    """Consecutive lists of ``size`` items (the last one shorter), read lazily."""
    chunk: list[Any] = []
    for item in items:
        chunk.append(item)
        if len(chunk) == size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def import_ray() -> Any:
    """The ``ray`` module, or a GazeAugError with the install hint."""
    try:
        import ray
    except ImportError as exc:
        raise GazeAugError(f"--engine ray needs the Ray package, which is not installed; {INSTALL_HINT}") from exc
    return ray


def check_address_form(address: str) -> tuple[str, int]:
    """``HOST:PORT`` split and checked for form (no network).

    Raises:
        GazeAugError: not ``HOST:PORT`` with a port from 1 to 65535.
    """
    host, sep, port = str(address).strip().rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise GazeAugError(
            f"--ray-address: expected HOST:PORT of a Ray head (ray start --head prints it), got {address!r}"
        )
    return host.strip("[]"), int(port)


def check_address(address: str, timeout_s: float = 3.0) -> None:
    """Check that a Ray head answers at ``address`` before connecting to it.

    Ray's own connection attempt to a wrong address retries for minutes and then
    ends the process; this asks the port for an HTTP/2 (gRPC) greeting instead,
    which a Ray head's GCS gives at once.

    Raises:
        GazeAugError: nothing listens there, or what listens is not a Ray head.
    """
    host, port = check_address_form(address)
    preface = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])  # + an empty SETTINGS frame
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as s:
            s.settimeout(timeout_s)
            s.sendall(preface)
            head = s.recv(9)
    except OSError as exc:
        raise GazeAugError(
            f"--ray-address {address}: no Ray cluster answers there ({exc.strerror or exc}); "
            "start one with `ray start --head` and give the address it prints"
        ) from None
    if len(head) < 9 or head[3] != 4:  # a gRPC server answers with its SETTINGS frame (type 4)
        raise GazeAugError(
            f"--ray-address {address}: something answers there, but not a Ray head "
            "(give the GCS address that `ray start --head` prints, default port 6379)"
        )


def node_name() -> str:
    """This process's machine, as failures name it: the host name and, in a Ray worker, the node's IP."""
    name = socket.gethostname()
    with contextlib.suppress(Exception):
        import ray

        if ray.is_initialized():
            name = f"{name} ({ray.util.get_node_ip_address()})"
    return name


@contextlib.contextmanager
def ray_session(engine: Engine) -> Iterator[Any]:
    """Ray connected for the run: joined at ``engine.address``, or a local instance started (and stopped after).

    A Ray already initialised by the caller is used as it is and left running.

    Yields:
        The ``ray`` module.
    """
    if engine.address == "auto" and os.environ.get("RAY_ADDRESS"):  # what "auto" joins first
        check_address(os.environ["RAY_ADDRESS"].strip())
    elif engine.address is not None and engine.address != "auto":
        check_address(engine.address)
    joining_with_token = engine.address is not None and "RAY_AUTH_MODE" not in os.environ and _token_available()
    if joining_with_token:
        # A head started by `ray start --head` requires its token; Ray sends the token it has only
        # when told to (it does for address="auto", not for an explicit address). Read at import.
        os.environ["RAY_AUTH_MODE"] = "token"
    os.environ.setdefault("RAY_BACKEND_LOG_LEVEL", "error")  # Ray's C++ retry warnings: one line of ours instead
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    if joining_with_token:
        with contextlib.suppress(Exception):  # Ray imported before: its configuration read the mode already
            from ray._private.authentication.authentication_token_setup import _enable_token_auth

            _enable_token_auth()
    options: dict[str, Any] = {
        "logging_level": logging.ERROR,
        "log_to_driver": False,
        "include_dashboard": False,
    }
    # Ray's processes are started with Ctrl-C blocked: a Ctrl-C in the terminal reaches the whole
    # process group, and Ray's daemons killed half-way through their start crash the driver or are
    # left behind. This process takes the Ctrl-C (after the start) and stops them in order.
    main = threading.current_thread() is threading.main_thread()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if main else None
    started = False
    try:
        try:
            if engine.address is not None:
                ray.init(address=engine.address, **options)
            else:
                ray.init(address="local", num_cpus=engine.workers or os.cpu_count() or 1, **options)
            started = True
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            hint = (
                "; a cluster with token authentication (the default of `ray start`) needs its token here: "
                "RAY_AUTH_TOKEN, or ~/.ray/auth_token copied from the head (docs/ray.md)"
                if engine.address is not None and engine.address != "auto"
                else ""
            )
            raise GazeAugError(f"could not start or join Ray ({engine.address or 'local'}): {first}{hint}") from None
        finally:
            if mask is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a Ctrl-C pressed meanwhile arrives here
        # Ray reports lost workers on stdout from a thread of its own: stdout is the command's result.
        with contextlib.redirect_stdout(sys.stderr):
            yield ray
    finally:
        if started:
            ray.shutdown()


def _token_available() -> bool:
    """Whether this machine holds a Ray authentication token (environment, token file, or ~/.ray/auth_token)."""
    if os.environ.get("RAY_AUTH_TOKEN"):
        return True
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or os.path.join(os.path.expanduser("~"), ".ray", "auth_token")
    return os.path.isfile(path)


class _Actor:
    """One stateful worker: ``setup(*setup_args)`` once, then ``work(block)`` per block."""

    def __init__(self, setup: Callable[..., Any], setup_args: tuple[Any, ...], cwd: str):
        import cv2

        # Relative paths (the dataset, -o, --faces) mean what they mean where the command runs: on a
        # shared filesystem the same folder exists on every node. Where it does not, absolute paths still work.
        with contextlib.suppress(OSError):
            os.chdir(cwd)
        cv2.setNumThreads(0)  # one actor per CPU: no OpenCV thread pool inside
        setup(*setup_args)

    def node(self) -> str:
        return node_name()

    def run(self, work: Callable[[Any], Any], block: Any) -> Any:
        return work(block)


def _lost_errors(ray: Any) -> tuple[type[BaseException], ...]:
    """Ray's errors that mean the actor, its process or its node is gone (the block is sent again)."""
    ex = ray.exceptions
    names = ("RayActorError", "WorkerCrashedError", "NodeDiedError", "ObjectLostError", "OwnerDiedError")
    return tuple(getattr(ex, n) for n in names if hasattr(ex, n))


def _start_failure(exc: BaseException) -> GazeAugError | None:
    """The error to stop with when an actor could not even start (its ``setup`` failed), else None."""
    text = str(exc)
    if "creation task" not in text and "__init__" not in text:
        return None
    last = [line for line in text.strip().splitlines() if line.strip()]
    why = last[-1].strip() if last else text
    if "No module named" in text:
        return GazeAugError(
            f"a Ray worker could not start: {why}. Every node needs gazeaug and its dependencies installed "
            "(the same environment as here), or a runtime_env that installs them (docs/ray.md)"
        )
    return GazeAugError(f"a Ray worker could not start: {why}")


def map_blocks(
    engine: Engine,
    blocks: Iterable[tuple[int, Any]],
    work: Callable[[Any], Any],
    setup: Callable[..., Any],
    setup_args: tuple[Any, ...] = (),
    *,
    on_result: Callable[[int, Any], None],
    interrupted: Callable[[], bool] = lambda: False,
) -> None:
    """Run ``work(block)`` for every block on Ray actors; hand the results over in block order.

    Args:
        engine: a Ray engine (``engine.kind == "ray"``).
        blocks: ``(index, block)`` pairs with indices 0, 1, 2... in order; read lazily (only the
            blocks in flight are held).
        work: a module-level function (actors import it by name), run in an actor after ``setup``.
        setup: a module-level function run once per actor.
        setup_args: its arguments.
        on_result: called on the driver with ``(index, result)`` in index order.
        interrupted: polled between results; True stops the run with KeyboardInterrupt.

    Raises:
        GazeAugError: the actors cannot start, or one block was lost with its actor too many times.
        Exception: what ``work`` raised (the run stops at the first such error).
        KeyboardInterrupt: ``interrupted()`` became true (the actors are stopped).
    """
    with ray_session(engine) as ray:
        n = engine.workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        remote = ray.remote(num_cpus=1, max_restarts=0, max_task_retries=0)(_Actor)
        lost = _lost_errors(ray)
        actors: dict[int, Any] = {}  # live actor id -> handle
        starting: dict[Any, int] = {}  # ready ref -> actor id
        load: dict[int, int] = {}  # live actor id -> blocks in flight
        inflight: dict[Any, tuple[int, int]] = {}  # result ref -> (actor id, block index)
        payload: dict[int, Any] = {}  # block index -> block, until its result is handed over
        todo: deque[int] = deque()  # blocks to send again (lost with their actor)
        attempts: dict[int, int] = {}
        done: dict[int, Any] = {}
        source = iter(blocks)
        exhausted = False
        next_out = 0
        started = 0
        any_ran = False

        actors_pending: dict[int, Any] = {}  # actor id -> handle, until its node() answered

        def start_actor() -> None:
            nonlocal started
            handle = remote.remote(setup, setup_args, os.getcwd())
            aid = started
            started += 1
            actors_pending[aid] = handle
            starting[handle.node.remote()] = aid

        def lose(aid: int, why: BaseException, block: int | None = None) -> None:
            """Actor ``aid`` is gone: its blocks in flight (and ``block``, already taken out) are sent again."""
            _log.info("Ray worker %d lost (%s): its blocks go to the others", aid, type(why).__name__)
            handle = actors.pop(aid, None) or actors_pending.pop(aid, None)
            load.pop(aid, None)
            mine = [] if block is None else [block]
            for ref, (a, b) in list(inflight.items()):
                if a == aid:
                    del inflight[ref]
                    mine.append(b)
            for b in sorted(mine, reverse=True):  # the earliest block first in the queue
                attempts[b] = attempts.get(b, 0) + 1
                if attempts[b] >= _MAX_ATTEMPTS:
                    raise WorkersLostError(f"block {b} was lost with its Ray worker {_MAX_ATTEMPTS} times; giving up")
                todo.appendleft(b)
            if handle is not None:
                with contextlib.suppress(Exception):
                    ray.kill(handle)
            if len(actors) + len(actors_pending) < n:  # a replacement, started where the cluster has room
                start_actor()

        def next_block() -> int | None:
            nonlocal exhausted
            if todo:
                return todo.popleft()
            if exhausted:
                return None
            item = next(source, None)
            if item is None:
                exhausted = True
                return None
            b, block = item
            payload[b] = block
            return b

        idle_since: float | None = None  # since when no actor is running (all lost or still starting)
        try:
            for _ in range(n):
                start_actor()
            while True:
                for aid, handle in actors.items():  # feed the live actors
                    while load[aid] < _DEPTH:
                        b = next_block()
                        if b is None:
                            break
                        inflight[handle.run.remote(work, payload[b])] = (aid, b)
                        _log.debug("block %d sent to worker %d", b, aid)
                        load[aid] += 1
                if exhausted and not payload:  # every block read has been handed over
                    break
                if not inflight and not starting:
                    raise WorkersLostError("every Ray worker was lost and none could be started again")
                if actors:
                    idle_since = None
                elif idle_since is None:
                    idle_since = time.monotonic()
                elif time.monotonic() - idle_since > _NO_WORKER_TIMEOUT_S:
                    raise WorkersLostError(
                        f"no Ray worker has been running for {_NO_WORKER_TIMEOUT_S:.0f} s: the cluster has no free "
                        "CPU for one (ray status shows its resources)"
                    )
                ready, _ = ray.wait([*inflight, *starting], num_returns=1, timeout=0.5)
                if interrupted():
                    raise KeyboardInterrupt
                for ref in ready:
                    if ref in starting:
                        aid = starting.pop(ref)
                        try:
                            ray.get(ref)
                        except lost as exc:
                            failure = _start_failure(exc)
                            if failure is not None and not any_ran:
                                raise failure from None
                            lose(aid, exc)
                            continue
                        actors[aid] = actors_pending.pop(aid)
                        load[aid] = 0
                        _log.info("Ray worker %d ready", aid)
                        continue
                    aid, b = inflight.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:
                        cause = getattr(exc, "cause", None)
                        raise (cause if isinstance(cause, Exception) else exc) from None
                    except lost as exc:
                        lose(aid, exc, b)
                        continue
                    any_ran = True
                    _log.debug("block %d done by worker %d", b, aid)
                    load[aid] -= 1
                    done[b] = result
                    while next_out in done:
                        on_result(next_out, done.pop(next_out))
                        payload.pop(next_out, None)
                        next_out += 1
        finally:
            for handle in [*actors.values(), *actors_pending.values()]:
                with contextlib.suppress(Exception):
                    ray.kill(handle)
