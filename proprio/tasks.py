"""One execution engine for the embarrassingly parallel jobs: ``proprio dataset``, ``gap-benchmark``, ``train-grid``.

A job is a list of :class:`Task` — a module-level function, its keyword arguments (each task carries its own seed,
so a result never depends on the backend, the worker count or the order tasks finish in) and a JSON-able
``config`` saying what it computes. :func:`run_tasks` runs them on one of two backends:

- ``local``: in this process (``workers=1``) or a ``concurrent.futures.ProcessPoolExecutor`` on this machine;
- ``ray``: `Ray <https://docs.ray.io>`_ tasks, one CPU each (plus a GPU where a task asks for one) — a local Ray
  instance started here with ``workers`` CPUs, or the cluster at ``address`` (``auto``, ``HOST:6379`` or
  ``ray://HOST:10001``). What a task needs on a worker travels with it: the ``proprio`` package through Ray's
  runtime environment (``py_modules``, :func:`runtime_env`), its inputs by value (``Shared`` values are put into
  Ray's object store once and handed to every task that uses them). No shared file system is assumed: a task
  returns its result to the driver, which stores it.

Results are stored by the driver, one file per task: ``store(task, result)`` writes what the job keeps (a
Recording, a model file) and returns a JSON-able record, which goes atomically (temporary file, then rename) to
``state_dir/<key>.json`` together with the task's config. A rerun skips every task whose record exists with the
same config (resume after a kill or a failure); a task that raises is reported with its config and traceback
(``state_dir/<key>.failed.json``, :attr:`TaskRun.failures`) while the others' results are kept. One tqdm bar counts
the tasks of the whole job. Ray is imported only when the ``ray`` backend is used (``pip install 'proprio[ray]'``).

One run at a time per ``state_dir``: :func:`run_tasks` holds its lock (:func:`proprio.io.locked_dir`), so a second
run into the same directory is refused (:class:`~proprio.io.DirectoryLocked`) instead of racing the first for the
same files; under the lock it first deletes the temporary files a killed run left there.

Shutdown: SIGTERM is handled like Ctrl-C (SIGINT) while :func:`run_tasks` runs in the main thread — it raises
``KeyboardInterrupt`` in the driver, so every ``finally`` runs: a half-written file is deleted
(:func:`proprio.io.atomic_path`), the local pool's worker processes are terminated (they ignore SIGINT themselves;
the driver stops them, whatever task they are in) and a Ray instance started here is shut down. No worker process
outlives the driver, and a rerun resumes from the tasks that were stored.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import signal
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import proprio
from proprio.io import LOCK_NAME, atomic_write_text, locked_dir

__all__ = ["Task", "Shared", "TaskFailure", "TaskRun", "run_tasks", "runtime_env", "import_ray", "init_ray", "BACKENDS",
           "RayMissingError", "sigterm_as_interrupt"]

BACKENDS = ("local", "ray")
_FORMAT = "proprio-task/v1"


class RayMissingError(ValueError):
    """``--backend ray`` without Ray installed (a user error: one line, exit 2 in the CLI)."""


@dataclass(frozen=True)
class Shared:
    """A task argument that many tasks share (a training split, a config): put into Ray's object store once."""
    value: Any


@dataclass(frozen=True)
class Task:
    """``fn(**kwargs)`` under a unique ``key``; ``config`` (JSON-able) states what it computes, with which seed —
    it is stored beside the result, printed when the task fails and compared on resume. ``num_gpus``: GPUs the task
    needs on the Ray backend (0: CPU only; ``"auto"``: 1 when the cluster has a GPU, else 0)."""
    key: str
    fn: Callable[..., Any]
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    config: Mapping[str, Any] = field(default_factory=dict)
    num_gpus: float | str = 0.0


@dataclass
class TaskFailure:
    key: str
    config: dict[str, Any]
    error: str
    traceback: str = ""

    def line(self) -> str:
        return f"task {self.key} failed: {self.error} (config: {json.dumps(self.config, sort_keys=True)})"


@dataclass
class TaskRun:
    """What :func:`run_tasks` did: ``records`` (key → stored record, tasks' order, finished ones only), which tasks
    ran now (``executed``) and which were already done (``skipped``), the ``failures``, wall ``seconds``."""
    records: dict[str, Any]
    executed: list[str]
    skipped: list[str]
    failures: list[TaskFailure]
    seconds: float
    backend: str
    workers: int

    def summary(self) -> str:
        s = (f"{len(self.executed)} task(s) run, {len(self.skipped)} already done, {len(self.failures)} failed "
             f"({self.backend}, {self.workers} worker(s), {self.seconds:.1f} s)")
        return "\n".join([s] + [f.line() for f in self.failures])


def import_ray() -> Any:
    """``ray``, or a one-line error saying how to install it."""
    try:
        import ray
    except ImportError:
        raise RayMissingError("--backend ray needs Ray: pip install 'proprio[ray]' (or pip install 'ray[tune]')") \
            from None
    return ray


def runtime_env(extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Ray runtime environment of proprio's tasks: the ``proprio`` package of this process as ``py_modules`` (so a
    worker runs the same code without having it installed), one BLAS/torch thread per task, plus ``extra`` (e.g.
    ``{"working_dir": "../shared"}`` for data a task reads by relative path)."""
    env: dict[str, Any] = {"py_modules": [str(Path(proprio.__file__).parent)],
                           "excludes": ["__pycache__", "*.pyc"],
                           "env_vars": {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}}
    for k, v in (extra or {}).items():
        env[k] = {**env[k], **v} if isinstance(env.get(k), dict) and isinstance(v, dict) else v
    return env


def _filename(key: str) -> str:
    safe = re.sub(r"[^A-Za-z0-9_.@+=-]", "_", key)[:80]
    return f"{safe}-{hashlib.sha1(key.encode()).hexdigest()[:8]}"


def _jsonable(config: Mapping[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(dict(config), sort_keys=True, default=str))


def _done_record(path: Path, config: dict[str, Any]) -> tuple[bool, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False, None
    if data.get("format") != _FORMAT or data.get("config") != config:
        return False, None
    return True, data.get("record")


def _call(fn: Callable[..., Any], **kwargs: Any) -> Any:
    return fn(**{k: v.value if isinstance(v, Shared) else v for k, v in kwargs.items()})


def _one_line(exc: BaseException) -> str:
    text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def run_tasks(tasks: Sequence[Task], state_dir: str | Path, store: Callable[[Task, Any], Any] | None = None,
              backend: str = "local", address: str | None = None, workers: int | None = None,
              progress: bool = True, desc: str = "tasks", env: Mapping[str, Any] | None = None,
              kept: Callable[[Task, Any], bool] | None = None) -> TaskRun:
    """Run the tasks not yet done in ``state_dir`` on ``backend`` (module docstring) and return what happened.

    ``store(task, result) -> record`` runs on this process for every finished task and returns the JSON-able record
    kept in ``state_dir`` (default: the result itself, which must then be JSON-able). ``workers``: processes
    (``local``; default 1) or the CPUs of the local Ray instance started here (default ``os.cpu_count()``; ignored
    with ``address`` or an already initialised Ray: see :func:`init_ray`). ``env``: extra runtime-environment entries
    (:func:`runtime_env`) of a Ray instance started here. ``kept(task, record)``: whether a recorded task's outputs are
    still there (e.g. its file was not deleted); a task whose outputs are gone runs again.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    if address and backend != "ray":
        raise ValueError("--address needs --backend ray")
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    keys = [t.key for t in tasks]
    dup = sorted({k for k in keys if keys.count(k) > 1})
    if dup:
        raise ValueError(f"task keys must be unique; repeated: {dup}")
    store = store or (lambda task, result: result)
    state = Path(state_dir)
    with sigterm_as_interrupt(), locked_dir(state):
        for stale in state.glob(".*"):                  # temporaries of a killed run (only ours live here)
            if stale.name != LOCK_NAME and stale.is_file():
                stale.unlink(missing_ok=True)
        return _run_locked(tasks, state, store, backend, address, workers, progress, desc, env, kept)


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While the block runs in the main thread, SIGTERM raises ``KeyboardInterrupt`` (module docstring: shutdown)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run_locked(tasks: Sequence[Task], state: Path, store: Callable[[Task, Any], Any], backend: str,
                address: str | None, workers: int | None, progress: bool, desc: str, env: Mapping[str, Any] | None,
                kept: Callable[[Task, Any], bool] | None) -> TaskRun:
    keys = [t.key for t in tasks]
    t0 = time.perf_counter()
    records: dict[str, Any] = {}
    configs = {t.key: _jsonable(t.config) for t in tasks}
    todo: list[Task] = []
    skipped: list[str] = []
    for t in tasks:
        done, record = _done_record(state / f"{_filename(t.key)}.json", configs[t.key])
        if done and (kept is None or kept(t, record)):
            records[t.key] = record
            skipped.append(t.key)
        else:
            todo.append(t)
    executed: list[str] = []
    failures: list[TaskFailure] = []

    from proprio.progress import progress_bar
    bar = progress_bar(total=len(tasks), initial=len(skipped), desc=desc, unit="task", enabled=progress)

    def finish(task: Task, result: Any = None, exc: BaseException | None = None, tb: str | None = None) -> None:
        name = _filename(task.key)
        if exc is None:
            try:
                record = store(task, result)
                atomic_write_text(state / f"{name}.json", json.dumps(
                    {"format": _FORMAT, "key": task.key, "config": configs[task.key], "record": record},
                    sort_keys=True, indent=1))
            except Exception as err:        # storing failed: the task counts as failed, the others go on
                exc = err
            else:
                records[task.key] = record
                executed.append(task.key)
                (state / f"{name}.failed.json").unlink(missing_ok=True)
        if exc is not None:
            tb = tb or "".join(traceback.format_exception(exc))
            failure = TaskFailure(task.key, configs[task.key], _one_line(exc), tb)
            failures.append(failure)
            atomic_write_text(state / f"{name}.failed.json", json.dumps(
                {"key": task.key, "config": failure.config, "error": failure.error, "traceback": tb}, indent=1))
        bar.update(1)
        if failures:
            bar.set_postfix(failed=len(failures))

    try:
        if backend == "ray":
            n = _run_ray(todo, finish, address, workers, env)
        elif (workers or 1) == 1 or len(todo) <= 1:
            n = 1
            for t in todo:
                try:
                    result = _call(t.fn, **t.kwargs)
                except Exception as exc:
                    finish(t, exc=exc)
                else:
                    finish(t, result)
        else:
            n = _run_pool(todo, finish, int(workers or 1))
    finally:
        bar.close()
    order = {k: i for i, k in enumerate(keys)}
    records = dict(sorted(records.items(), key=lambda kv: order[kv[0]]))
    executed.sort(key=order.get)
    return TaskRun(records, executed, skipped, failures, time.perf_counter() - t0, backend, n)


def _worker_init() -> None:
    """A pool worker leaves interrupts to the driver: Ctrl-C (sent to the whole process group) is ignored here, and
    SIGTERM — from the driver stopping the pool — ends the worker at once (not the handler it inherited)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _run_pool(todo: list[Task], finish: Callable[..., None], workers: int) -> int:
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(max_workers=workers, initializer=_worker_init)
    try:
        futs = {pool.submit(_call, t.fn, **t.kwargs): t for t in todo}
        for fut in as_completed(futs):
            exc = fut.exception()
            finish(futs[fut], None if exc else fut.result(), exc)
    except BaseException:
        # interrupted (Ctrl-C, SIGTERM) or the driver failed: stop the workers in whatever task they are in.
        # ProcessPoolExecutor has no public way to stop running tasks; its worker processes are ``_processes``.
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(5.0)
            if p.is_alive():
                p.kill()
                p.join()
        raise
    pool.shutdown()
    return workers


def init_ray(address: str | None = None, num_cpus: int | None = None, env: Mapping[str, Any] | None = None) -> Any:
    """Start a local Ray instance with ``num_cpus`` (default ``os.cpu_count()``) or connect to the cluster at
    ``address``, with proprio's job-level runtime environment (:func:`runtime_env`: Ray accepts local directories to
    upload only there). :func:`run_tasks` calls it when Ray is not initialised yet; call it yourself (and
    ``ray.shutdown()``) to keep one instance over several jobs. Returns the ``ray`` module."""
    ray = import_ray()
    kwargs: dict[str, Any] = {"log_to_driver": False, "include_dashboard": False, "runtime_env": runtime_env(env)}
    if address:
        kwargs["address"] = address
    else:
        kwargs["num_cpus"] = num_cpus or os.cpu_count() or 1
    try:
        ray.init(**kwargs)
    except ConnectionError as exc:
        raise ValueError(f"--address {address}: cannot connect to a Ray cluster ({_one_line(exc)})") from None
    return ray


def _run_ray(todo: list[Task], finish: Callable[..., None], address: str | None, workers: int | None,
             env: Mapping[str, Any] | None) -> int:
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        init_ray(address, workers, env)
    try:
        n = int(ray.cluster_resources().get("CPU", 1))
        if not todo:
            return n
        has_gpu = ray.cluster_resources().get("GPU", 0) >= 1
        remote = ray.remote(_call)
        shared: dict[int, Any] = {}
        pending: dict[Any, Task] = {}
        for t in todo:
            kw = {}
            for k, v in t.kwargs.items():
                if isinstance(v, Shared):
                    if id(v) not in shared:
                        shared[id(v)] = ray.put(v.value)
                    v = shared[id(v)]
                kw[k] = v
            gpus = (1.0 if has_gpu else 0.0) if t.num_gpus == "auto" else float(t.num_gpus)
            ref = remote.options(num_cpus=1, num_gpus=gpus, max_retries=0, retry_exceptions=False,
                                 name=t.key[:100]).remote(t.fn, **kw)
            pending[ref] = t
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                t = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:          # RayTaskError wraps the task's exception
                    cause = getattr(exc, "cause", None)
                    finish(t, exc=cause if isinstance(cause, BaseException) else exc, tb=str(exc))
                else:
                    finish(t, result)
        return n
    finally:
        if started:
            ray.shutdown()
