"""The sweep's runs as Ray tasks: connecting to Ray (a local instance, or a ``ray start`` cluster with its token
authentication), one ``sgfd-zoo train`` per task with its output in the run's log file, live progress, Ctrl-C
stopping each run at a checkpoint, and a cluster that goes away noticed as such (Ray's core would end the
driver about a minute later, with no word of what happened to the runs)."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import socket
import sys
import tempfile
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from sgfd_zoo import training
from sgfd_zoo.arguments import TrainingStopped, ZooError
from sgfd_zoo.config_checks import first_line
from sgfd_zoo.runs.folders import NoUsableCheckpoint
from sgfd_zoo.runs.locks import HEARTBEAT_SECONDS, STALE_SECONDS, live_holder
from sgfd_zoo.sweep.plan import Job, run_resources
from sgfd_zoo.sweep.progress import LiveView, ProgressBoard, progress_block, returns_text

BOARD_NAME = "sgfd-zoo sweep progress"  # the progress board actor, in this sweep's Ray namespace
#: Seconds between two checks that the cluster still answers, while runs are pending.
LIVENESS_INTERVAL = 5.0
#: Failed checks in a row after which the cluster counts as gone (well before Ray's own minute).
LIVENESS_FAILURES = 2


class ClusterLost(Exception):
    """The Ray cluster stopped answering while runs were pending.

    :param reason: what was seen, in one line
    """


# -- one run, in a Ray worker -----------------------------------------------------------------------


def train_job(job: Job, train_args: list[str], cwd: str, board: Any = None) -> bool:
    """
    The Ray task: ``sgfd-zoo train`` of ``job`` in this worker process, its output appended to the job's
    log file, its progress sent to ``board``. Resumes from the run's checkpoint when it has one, and starts
    it again from step 0 when none of its checkpoints verifies. Returns whether it resumed.

    A retry after a lost node finds the run locked by the attempt that died there: it waits until that lock's
    heartbeat is stale (:data:`sgfd_zoo.runs.locks.STALE_SECONDS`), then takes it over.

    :param job: The run
    :param train_args: Flags for ``sgfd-zoo train`` besides --algo, --env, --seed, -f
    :param cwd: The driver's working directory (relative paths in ``train_args`` are relative to it)
    :param board: A ``ProgressBoard`` actor handle, or None
    """
    if os.path.isdir(cwd):
        os.chdir(cwd)
    argv = ["--algo", job.algo, "--env", job.env_id, "--seed", str(job.seed), "-f", str(job.folder)]
    argv += ["--run-id", str(job.run_id), *train_args]
    reporter = None if board is None else (lambda report: board.report.remote(job.name, report))
    job.log_file.parent.mkdir(parents=True, exist_ok=True)
    with _output_to(job.log_file):
        _wait_for_lock(job)
        # Decided here, not when planning: a retry after a crash continues from the newest checkpoint.
        resume = job.run.checkpoint is not None
        what = "resuming from its checkpoint" if resume else "new run"
        print(f"=== sgfd-zoo sweep, {time.strftime('%Y-%m-%d %H:%M:%S')}: {job} in {job.run_dir} ({what})", flush=True)
        try:
            try:
                training.train([*argv, "--resume"] if resume else argv, progress_reporter=reporter)
            except NoUsableCheckpoint as error:
                print(f"{error}\n=== so starting it again from step 0", flush=True)
                resume = False
                training.train(argv, progress_reporter=reporter)
        except (TrainingStopped, ZooError) as error:
            print(f"sgfd-zoo train: {error}", flush=True)  # where it stopped and how it goes on, in one line
            raise
        except SystemExit as error:
            # argparse exits on bad flags; a SystemExit would end the Ray worker (a "crash" Ray retries).
            sys.stderr.flush()
            raise RuntimeError(f"sgfd-zoo train exited with status {error.code}: {_last_line(job.log_file)}") from None
        except BaseException:
            traceback.print_exc()
            raise
    if not job.run.finished:
        raise RuntimeError(f"sgfd-zoo train ended, but {job.run_dir} is not a finished run")
    return resume


def _wait_for_lock(job: Job) -> None:
    """Until no live writer holds the run's lock, or for as long as a dead one's takes to go stale."""
    deadline = time.monotonic() + STALE_SECONDS + 2 * HEARTBEAT_SECONDS
    said = False
    while (holder := live_holder(job.run_dir)) is not None:
        if time.monotonic() > deadline:
            return  # the train refuses it in one line
        if not said:
            print(f"=== waiting: {job.run_dir} is locked by {holder.describe()}", flush=True)
            said = True
        time.sleep(min(HEARTBEAT_SECONDS, 10.0))


@contextlib.contextmanager
def _output_to(path: Path) -> Iterator[None]:
    """Send this process's stdout and stderr (file descriptors, so C libraries' output too) to ``path``."""
    # O_NOFOLLOW: a link put in the log's place is refused (ELOOP), not appended through
    log = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW, 0o644)
    try:
        with _descriptors_to(log, (1, 2)):
            yield
    finally:
        os.close(log)


@contextlib.contextmanager
def _descriptors_to(target: int, descriptors: tuple[int, ...]) -> Iterator[None]:
    """File ``descriptors`` (1: stdout, 2: stderr) made copies of descriptor ``target`` while the block runs, then
    given back; Python's buffered streams are flushed at both ends, so no line lands on the wrong side."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(descriptor) for descriptor in descriptors]
    try:
        for descriptor in descriptors:
            os.dup2(target, descriptor)
        yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for descriptor, copy in zip(descriptors, saved, strict=True):
            os.dup2(copy, descriptor)
            os.close(copy)


def _last_line(path: Path, tail: int = 4096) -> str:
    with path.open("rb") as handle:
        handle.seek(max(path.stat().st_size - tail, 0))
        lines = [line.strip() for line in handle.read().decode(errors="replace").splitlines()]
    return next((line for line in reversed(lines) if line), "")


# -- the driver -------------------------------------------------------------------------------------


def run_jobs(jobs: list[Job], train_args: list[str], args: argparse.Namespace) -> list[tuple[Job, str]]:
    """Run ``jobs`` as Ray tasks, showing their progress; returns the failed ones with a one-line reason.
    Ray is shut down after. Ctrl-C stops the running runs at a checkpoint each, then raises
    KeyboardInterrupt; a second Ctrl-C stops them at once. A cluster that stops answering raises
    :class:`ClusterLost`."""
    prepare_ray_environment(args)  # before Ray is imported: it reads these variables when it is
    import ray

    start_ray(args)
    try:
        train_args, packed = run_resources(args, train_args, *gpu_node_shares())
        if packed is not None:
            print(f"sweep: {packed}")
        board = ray.remote(num_cpus=0)(ProgressBoard).options(name=BOARD_NAME).remote()
        task = ray.remote(
            num_cpus=args.cpus_per_run,
            num_gpus=args.gpus_per_run,
            # a run's replay buffer reserved in Ray's memory, so that a node never holds more buffers than fit
            memory=args.replay_bytes if packed is not None else 0,
            # A fresh process per run: rl-zoo3's train() sets process-wide state (torch threads, seeds,
            # sys.argv, the algorithm table), and a long run's memory is given back when it ends.
            max_calls=1,
            max_retries=args.max_retries,
            retry_exceptions=False,
        )(train_job)
        cwd = os.getcwd()
        pending = {task.options(name=f"sweep {job}").remote(job, train_args, cwd, board): job for job in jobs}
        failures: list[tuple[Job, str]] = []
        with LiveView(args.progress_interval) as view:
            try:
                _wait_for(pending, jobs, board, view, failures, Liveness(ray.get_runtime_context().gcs_address))
            except KeyboardInterrupt:
                _stop_at_checkpoints(pending, view)
                raise
        return failures
    finally:
        ray.shutdown()


def gpu_node_shares() -> tuple[float | None, float | None]:
    """The CPU cores and the memory for tasks (Ray's ``memory``, bytes) per GPU of the cluster's live GPU nodes (the
    fewest, where nodes differ); (None, None) without a GPU."""
    import ray

    nodes = [node["Resources"] for node in ray.nodes() if node.get("Alive")]
    gpu_nodes = [node for node in nodes if node.get("GPU", 0) > 0]
    if not gpu_nodes:
        return None, None
    cores = min(node.get("CPU", 0.0) / node["GPU"] for node in gpu_nodes)
    return cores, min(node.get("memory", 0.0) / node["GPU"] for node in gpu_nodes) or None


class Liveness:
    """Whether the cluster's head (its GCS) still takes connections; checked every :data:`LIVENESS_INTERVAL`.

    :param address: the GCS's host:port
    """

    def __init__(self, address: str):
        self.address = address
        self.failures = 0
        self._next = 0.0

    def check(self, now: bool = False) -> None:
        """A :class:`ClusterLost` after :data:`LIVENESS_FAILURES` failed checks in a row; ``now``: check at once."""
        if not now and time.monotonic() < self._next:
            return
        self._next = time.monotonic() + LIVENESS_INTERVAL
        try:
            _connect_once(self.address, timeout=LIVENESS_INTERVAL / 2)
        except OSError as error:
            self.failures += 1
            if self.failures >= LIVENESS_FAILURES or now:
                raise ClusterLost(f"its head at {self.address} no longer answers ({error})") from None
        else:
            self.failures = 0


def _wait_for(
    pending: dict[Any, Job],
    jobs: list[Job],
    board: Any,
    view: LiveView,
    failures: list[tuple[Job, str]],
    liveness: Liveness,
) -> None:
    """Until no run is ``pending``: show their progress, a line per run as it ends, the failed ones added to
    ``failures``; a :class:`ClusterLost` when the cluster stops answering."""
    import ray

    status: dict[str, str] = {}
    reports: dict[str, dict[str, Any]] = {}
    while pending:
        liveness.check()
        done, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
        if board is not None:
            try:
                reports = ray.get(board.snapshot.remote(), timeout=30)
            except (ray.exceptions.RayActorError, ray.exceptions.GetTimeoutError) as error:
                # Only the live view is lost: the runs report to a dead actor, which Ray drops.
                board, reports = None, {}
                view.message(f"sweep: the progress board stopped ({_reason(error)}); the runs go on")
        for ref in done:
            job = pending[ref]
            count = f"[{len(jobs) - len(pending) + 1}/{len(jobs)}]"
            report = reports.get(job.name, {})
            try:
                resumed = ray.get(ref)
            except ray.exceptions.RayError as error:
                if not isinstance(error, ray.exceptions.RayTaskError):  # the worker or its node died: why?
                    liveness.check(now=True)
                failures.append((job, _reason(error)))
                status[job.name] = "FAILED"
                view.message(f"{count} FAILED {job}: {failures[-1][1]} (log: {job.log_file})")
            else:
                status[job.name] = "finished"
                evaluated = returns_text(report)
                view.message(
                    f"{count} finished {job}{' (resumed)' if resumed else ''}"
                    + (f": last evaluation during training {evaluated}" if evaluated else "")
                    + f" ({job.run_dir})"
                )
            del pending[ref]
        view.show(progress_block([job.name for job in jobs], reports, status), force=not pending)


def _stop_at_checkpoints(pending: dict[Any, Job], view: LiveView) -> None:
    """Stop every ``pending`` run as a Ctrl-C stops ``sgfd-zoo train`` (at a checkpoint, at a step boundary),
    wait for them, and say where each stopped. A waiting run is dropped. A second Ctrl-C stops the waiting
    (then ``ray.shutdown`` ends the runs where they are)."""
    import ray

    view.message(
        "sweep: interrupted; the running runs stop at a checkpoint each (Ctrl-C again: at once, losing the steps "
        "since their last checkpoint)"
    )
    # A running Ray task's cancel raises KeyboardInterrupt in it through its SIGINT handler: the train's own
    # deferred Ctrl-C, which checkpoints and stops. A terminal's Ctrl-C does not reach the workers themselves
    # (each has a process group of its own), so this is their only one.
    before = {job: job.run.checkpoint for job in pending.values()}
    for ref in pending:
        ray.cancel(ref)
    ray.wait(list(pending), num_returns=len(pending))
    for job in pending.values():
        run = job.run
        checkpoint = None if run.finished else run.checkpoint
        if run.finished:
            view.message(f"finished {job} ({job.run_dir})")
        elif checkpoint is not None and checkpoint != before[job]:
            view.message(f"stopped {job} at its checkpoint at {checkpoint.num_timesteps} steps ({job.run_dir})")


# -- connecting -------------------------------------------------------------------------------------


#: Ray's documented switch of multi-node clusters (read when Ray is imported): "0" makes a node take the loopback
#: address as its own, as Ray does on macOS and Windows, so that its GCS, raylet and workers listen on loopback only.
CLUSTERS_VARIABLE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
#: Ray's documented token authentication: its mode, and where the token is looked for (highest precedence first)
AUTH_MODE_VARIABLE, TOKEN_VARIABLE, TOKEN_PATH_VARIABLE = "RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH"


def prepare_ray_environment(args: argparse.Namespace) -> None:
    """Ray's environment variables for this sweep, set before Ray is imported (it reads them then), each left as
    the user set it:

    - a local instance (no ``--address``): multi-node clusters off, so that it binds to loopback (on Linux Ray would
      otherwise replace 127.0.0.1 by the machine's reachable address, and listen on every interface);
    - a cluster: token authentication when this machine has a token (what ``ray start`` does itself when it finds
      one; a token sent to a cluster without authentication is ignored).
    """
    if args.address is None:
        os.environ.setdefault(CLUSTERS_VARIABLE, "0")
    elif AUTH_MODE_VARIABLE not in os.environ and has_ray_token():
        os.environ[AUTH_MODE_VARIABLE] = "token"


def has_ray_token() -> bool:
    """Whether this machine has a Ray token where Ray looks: ``RAY_AUTH_TOKEN``, the file ``RAY_AUTH_TOKEN_PATH``
    names, or ``~/.ray/auth_token``."""
    if os.environ.get(TOKEN_VARIABLE):
        return True
    path = os.environ.get(TOKEN_PATH_VARIABLE)
    return Path(path).is_file() if path else (Path.home() / ".ray" / "auth_token").is_file()


def start_ray(args: argparse.Namespace) -> None:
    """``ray.init``: on the cluster ``args.address`` names, else a new local instance sized by ``args``, bound to
    loopback (:func:`prepare_ray_environment`, which must run before Ray is imported: a local instance that does
    not bind to loopback is refused in one line)."""
    prepare_ray_environment(args)
    import ray

    # Each run's output is in its log file; Ray's own warnings (token authentication, ...) only when asked for.
    quiet: dict[str, Any] = {
        "log_to_driver": False,
        "logging_level": logging.WARNING if args.ray_logs else logging.ERROR,
    }
    if args.address is not None:
        _connect(args.address, quiet, args.ray_logs)
        cpus, gpus = ray.cluster_resources().get("CPU", 0), ray.cluster_resources().get("GPU", 0)
        print(f"sweep: Ray cluster at {args.address}: {cpus:g} CPUs, {gpus:g} GPUs")
        return
    # "local": a new instance even if `ray start` left one running on this machine (or RAY_ADDRESS names one).
    ray.init(address="local", num_cpus=args.num_cpus, include_dashboard=False, **quiet)
    listening = ray.nodes()[0]["NodeManagerAddress"]
    if listening != LOOPBACK:
        ray.shutdown()
        raise ZooError(
            f"the local Ray instance took the address {listening}, not {LOOPBACK}: its processes would listen on "
            f"every interface (set {CLUSTERS_VARIABLE}=0 before Ray is imported, as sgfd-zoo does when it imports "
            "Ray itself); or start a cluster as you need it (ray start) and give it with --address"
        )
    cpus, gpus = ray.cluster_resources().get("CPU", 0), ray.cluster_resources().get("GPU", 0)
    if args.ray_logs:
        print(f"sweep: local Ray instance: {cpus:g} CPUs, {gpus:g} GPUs")
    if args.gpus_per_run and args.gpus_per_run > gpus:
        # Ray would wait forever for a GPU no node of this instance has.
        ray.shutdown()
        raise ZooError(f"--gpus-per-run {args.gpus_per_run:g}: Ray sees {gpus:g} GPUs on this machine")


LOOPBACK = "127.0.0.1"


def _connect(address: str, quiet: dict[str, Any], show_ray_output: bool) -> None:
    """``ray.init(address=...)``, with Ray's token authentication when this machine has a token (a token sent to
    a cluster without authentication is ignored), and a failure as one line: authentication named as such,
    with its fix. Ray's own retries print a line a second to stderr: kept out of sight unless asked for."""
    import ray

    _check_reachable(address)
    with tempfile.TemporaryFile("w+") as captured:
        try:
            with _stderr_to(None if show_ray_output else captured):
                ray.init(address=address, **quiet)
            return
        except (ConnectionError, ValueError, RuntimeError, ray.exceptions.RayError) as error:
            captured.seek(0)
            said, reason = f"{error} {captured.read()}", first_line(error)
    if "AuthToken" in said or "Unauthenticated" in said or "authentication" in said.lower():
        has_token = has_ray_token()
        raise ZooError(
            f"--address {address}: the Ray cluster requires token authentication and "
            + ("refused this machine's token" if has_token else "this machine has no token")
            + ": copy the cluster's token (`ray get-auth-token` on its head node) into ~/.ray/auth_token, or set "
            "RAY_AUTH_TOKEN (or RAY_AUTH_TOKEN_PATH) to it, then run the same command"
        ) from None
    raise ZooError(f"--address {address}: no Ray cluster to connect to ({reason})")


@contextlib.contextmanager
def _stderr_to(handle: Any) -> Iterator[None]:
    """File descriptor 2 (Ray's C++ core writes there) into ``handle`` while the block runs; None: unchanged."""
    if handle is None:
        yield
        return
    with _descriptors_to(handle.fileno(), (2,)):
        yield


def _check_reachable(address: str, timeout: float = 10.0) -> None:
    """
    Refuse a host:port nothing listens on: Ray itself retries such an address for minutes (13 on our
    machine) before it gives up. Other forms ('auto', 'ray://...') are left to Ray.

    :param address: The --address value
    :param timeout: Seconds to wait for a TCP connection
    """
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return
    try:
        _connect_once(address, timeout)
    except OSError as error:
        raise ZooError(f"--address {address}: no Ray cluster answers there ({error})") from None


def _connect_once(address: str, timeout: float) -> None:
    """Open a TCP connection to ``host:port`` (an IPv6 host in brackets) and close it; an OSError when none opens
    within ``timeout`` seconds."""
    host, _, port = address.rpartition(":")
    with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
        pass


def _reason(error: Exception) -> str:
    """One line for the summary: the run's own exception when it raised one, else what Ray says."""
    cause = getattr(error, "cause", None)
    shown = cause if isinstance(cause, BaseException) else error
    return f"{type(shown).__name__}: {first_line(shown)}"
