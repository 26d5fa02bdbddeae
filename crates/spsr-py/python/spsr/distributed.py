"""Reconstruction on a Dask cluster: the slabs of ``spsr reconstruct --slabs K`` as tasks.

A cloud too large for one machine's memory or patience is cut into ``K`` slabs along one axis
(Kazhdan & Hoppe, *Distributed Poisson Surface Reconstruction*, 2023, as the reference's
``PoissonReconServer`` and ``PoissonReconClient`` do). Each slab's samples, constraints, fine
solve and extraction run as a Dask task on any worker; the coarse levels are solved once from
every slab's sums; the slabs' parts are stitched into one watertight mesh. The mesh is the same
bytes as ``spsr reconstruct IN... -o OUT --slabs K`` on one machine.

Every step reads and writes one *job folder* (inside ``work_dir``), which must be reachable at
the same path from every worker (a shared file system: NFS, Lustre, a cloud file share); the
input files and the output path are read and written by the workers too. A task that dies
(its worker killed, its machine lost) leaves nothing half-written and is simply run again by
Dask on another worker. The job folder is deleted when the run ends, whether it succeeded or
not.

Needs Dask's ``distributed`` package: ``pip install "spsr[distributed]"``.

Examples
--------
On one machine, with a local cluster of worker processes::

    import spsr.distributed
    stats = spsr.distributed.reconstruct(["tile_0.laz", "tile_1.laz"], "site.ply",
                                         slabs=8, depth=12)

On a cluster whose scheduler runs at ``tcp://10.0.0.5:8786``::

    from dask.distributed import Client
    client = Client("tcp://10.0.0.5:8786")
    stats = spsr.distributed.reconstruct(tiles, "/shared/site.ply", client=client,
                                         work_dir="/shared/tmp", depth=13)

From a shell, with ``spsr reconstruct``'s flags::

    python -m spsr.distributed --scheduler tcp://10.0.0.5:8786 tiles/*.laz -o site.ply \\
        --depth 13 --slabs 32 --work-dir /shared/tmp
"""

from __future__ import annotations

import inspect
import os
import sys
import time
import uuid
import warnings
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from . import FileFormatError, _method_keywords, _spsr
from . import reconstruct as _reconstruct

__all__ = ["reconstruct", "main"]

PathLike = Union[str, "os.PathLike[str]"]

# Keywords of spsr.reconstruct that a slab run cannot take yet, and why.
_REFUSED = {
    "colors": "colours given as arrays are carried only by in-core runs "
    "(colours stored in the input files are carried)",
    "weights": "per-point weights are carried only by in-core runs",
    "point_attributes": "attributes given as arrays are carried only by in-core runs "
    "(attributes stored in the input files are carried)",
    "keep_implicit": "the implicit function lives in the slabs' tasks and is not kept; "
    "reconstruct in-core to evaluate it",
}
# Keywords of spsr.reconstruct that a slab run takes only at their defaults, and why: the
# depth of a width or of the spacing is resolved over the whole cloud in memory, and the
# slabs never hold the whole implicit function for a grid.
_WHOLE_CLOUD = "the depth is then chosen over the whole cloud in memory"
_GIVE_DEPTH = "give depth= instead (spsr.reconstruct reports the depth it chose in stats['depth'])"
_DEFAULT_ONLY = {
    "width": f"{_WHOLE_CLOUD}; {_GIVE_DEPTH}",
    "grid_res": "the slabs never hold the whole implicit function; reconstruct in-core for a grid",
}
# Keywords of spsr.reconstruct that are not parameters of the method.
_NOT_PARAMS = {"points", "normals", "threads"}
# The trimming's keywords: the job trims the whole mesh in its last step.
_TRIM = ("trim", "min_island_area", "hole_area")

# The steps of one run, in order: (step, whether it is per slab); the noise phase runs only
# when the noise is adaptive, and each solver cycle after the first is the coordinator's
# "cycle" step, then the slabs' "solve" again.
_NOISE_STEPS = (("noise", True), ("smoothing", False))
_SOLVE_STEPS = (("coarse", True), ("solve_coarse", False), ("solve", True))
_CYCLE_STEPS = (("cycle", False), ("solve", True))
_LAST_STEPS = (("iso", False), ("extract", True))


def _steps(noise: bool, cycles: int) -> List[Tuple[str, bool]]:
    """The steps of a job with adaptive noise or not and `cycles` solver cycles."""
    return (
        list(_NOISE_STEPS if noise else ())
        + list(_SOLVE_STEPS)
        + list(_CYCLE_STEPS) * max(cycles - 1, 0)
        + list(_LAST_STEPS)
    )


def _parameter_defaults() -> Dict[str, Any]:
    """The method's keywords and their defaults: spsr.reconstruct's, so both stay one."""
    out = {}
    for name, p in inspect.signature(_reconstruct).parameters.items():
        if name in _NOT_PARAMS or name in _REFUSED or name in _TRIM:
            continue
        out[name] = p.default
    return out


def _trim_json(params: Dict[str, Any]) -> Optional[str]:
    """The job's trimming (checked by the library) from reconstruct's trimming keywords, which
    are taken out of `params`; None without trim=."""
    defaults = inspect.signature(_reconstruct).parameters
    kw = {name: params.pop(name, defaults[name].default) for name in _TRIM}
    return _spsr.slab_trim(kw["trim"], kw["min_island_area"], kw["hole_area"])


def _params_json(params: Dict[str, Any]) -> str:
    """The job's parameters (checked by the library) from reconstruct's keywords."""
    kw = _parameter_defaults()
    for name, value in params.items():
        if name in _REFUSED:
            raise ValueError(f"{name}= is not supported on a cluster: {_REFUSED[name]}")
        if name not in kw:
            raise TypeError(f"reconstruct() got an unexpected keyword argument '{name}'")
        if name in _DEFAULT_ONLY and value is not None:
            raise ValueError(f"{name}= is not supported on a cluster: {_DEFAULT_ONLY[name]}")
        if name == "depth" and isinstance(value, str) and value.strip().lower() == "auto":
            raise ValueError(f"depth='auto' is not supported on a cluster: {_WHOLE_CLOUD}; {_GIVE_DEPTH}")
        kw[name] = value
    return _spsr.slab_params(_method_keywords(**kw))


def _paths(inputs: Union[PathLike, Sequence[PathLike]]) -> List[str]:
    """The input files as absolute paths (the workers may run in other folders)."""
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    out = [os.path.abspath(os.fspath(p)) for p in inputs]
    if not out:
        raise ValueError("no input files: give at least one point file")
    return out


# --------------------------------------------------------------------------------------
# The tasks (module-level functions, so that Dask sends them to the workers by name)


def _prepare_task(
    inputs: List[str],
    work_dir: str,
    slabs: int,
    params: str,
    threads: Optional[int],
    trim: Optional[str] = None,
) -> Tuple[str, int, bool, int]:
    folder, k, noise, cycles = _spsr.slab_prepare(inputs, work_dir, slabs, params, threads, trim)
    return os.fspath(folder), k, noise, cycles


def _step_task(
    step: str,
    folder: str,
    slab: Optional[int],
    threads: Optional[int],
    fault: Optional[Tuple[str, int, str]] = None,
) -> None:
    if fault is not None and (step, slab) == fault[:2]:
        # Tests only: this worker dies the first time it runs this task (the marker file
        # records that it has), as a machine lost mid-task would.
        try:
            os.close(os.open(fault[2], os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            pass
        else:
            os._exit(1)
    _spsr.slab_step(step, folder, slab, threads)


def _finish_task(folder: str, output: str) -> Dict[str, Any]:
    return _spsr.slab_finish(folder, output)


def _remove_task(folder: str) -> None:
    _spsr.slab_remove(folder)


# --------------------------------------------------------------------------------------
# The coordinator


def _distributed() -> Any:
    try:
        import distributed
    except ImportError as e:  # pragma: no cover (the extra is installed in the tests)
        raise ImportError(
            'spsr.distributed needs Dask\'s "distributed" package: pip install "spsr[distributed]"'
        ) from e
    return distributed


def _settle(client: Any, futures: List[Any]) -> List[Any]:
    """The results of `futures`, once all of them have ended; the first failure (in slab
    order) is raised after the others have stopped, so that nothing writes into the job
    folder afterwards.

    The futures are released once their results are here: while a future is held, Dask keeps
    its result on a worker and, if that worker dies, runs the task again to get it back. A
    step run again after its phase would write into the job folder out of order, and the
    preparation run again would make a second job folder that nothing removes."""
    _distributed().wait(futures)
    try:
        for f in futures:
            if f.status != "finished":
                error = f.exception()
                client.cancel([g for g in futures if g is not f])
                raise error
        return [f.result() for f in futures]
    finally:
        for f in futures:
            f.release()


def _run_steps(
    client: Any,
    folder: str,
    slabs: int,
    noise: bool,
    cycles: int,
    token: str,
    threads: Optional[int],
    fault: Optional[Tuple[str, int, str]],
) -> List[Tuple[str, float]]:
    """Runs the job's steps in order; returns each run's name and wall time in seconds."""
    timings = []
    for i, (step, per_slab) in enumerate(_steps(noise, cycles)):
        start = time.perf_counter()
        # Dask keeps a result by its key: a step run once per cycle needs one key per run.
        name = f"{step}{i}"
        if per_slab:
            futures = client.map(
                _step_task,
                [step] * slabs,
                [folder] * slabs,
                list(range(slabs)),
                [threads] * slabs,
                [fault] * slabs,
                key=[f"spsr-{name}-{token}-{s}" for s in range(slabs)],
            )
        else:
            futures = [
                client.submit(
                    _step_task, step, folder, None, threads, None, key=f"spsr-{name}-{token}"
                )
            ]
        _settle(client, futures)
        timings.append((step, time.perf_counter() - start))
    return timings


def reconstruct(
    inputs: Union[PathLike, Sequence[PathLike]],
    output: PathLike,
    *,
    client: Any = None,
    slabs: Optional[int] = None,
    work_dir: Optional[PathLike] = None,
    threads: Optional[int] = None,
    _fault: Optional[Tuple[str, int, str]] = None,
    **params: Any,
) -> Dict[str, Any]:
    """Reconstructs the cloud in ``inputs`` (one file or several tiles, read as one cloud, in
    any format spsr reads; normals needed) on a Dask cluster and writes the mesh to ``output``
    (binary PLY).

    Parameters
    ----------
    inputs, output
        Paths as the workers see them (relative paths are made absolute here, so the client
        and the workers should share a file system at the same paths).
    client
        A ``distributed.Client``. None: a local cluster of worker processes on this machine
        (one per core), closed at the end.
    slabs
        The number of slabs (tasks per phase); None: twice the number of workers. Fewer are
        made when fewer slabs of the cloud hold points. The mesh depends on the slab count
        (within the solver's tolerance) but never on the workers, their threads or the order
        in which the tasks run.
    work_dir
        The folder in which the job folder is made (shared by every worker): default, the
        output's folder.
    threads
        Threads of each task; None: all the worker's cores.
    **params
        The method's parameters, as keywords of :func:`spsr.reconstruct` (``depth``,
        ``degree``, ``samples_per_node``, ``noise``, ``max_memory`` ...), with the same
        defaults. ``density=True`` writes each vertex's density; ``trim=`` (with
        ``min_island_area`` and ``hole_area``) trims the mesh with one threshold for the
        whole mesh, as in one piece, in the last task, which holds the whole mesh in memory.
        ``colors``, ``weights``, ``point_attributes`` and ``keep_implicit`` are refused, and
        so are ``width``, ``depth="auto"`` and ``grid_res`` (a slab run takes a plain depth
        and makes no grid).

    Returns
    -------
    dict
        ``vertices``, ``faces``, ``pieces``, ``closed``, ``open_edges``, ``slabs``,
        ``points``, ``dropped``, ``samples``, ``iso_value``, ``mean_sample_depth``,
        ``warnings`` (also raised as ``RuntimeWarning``), ``timings`` (each step's name and
        wall time in seconds, in the order they ran: ``prepare``, the per-slab and coordinator
        steps, ``finish``) and ``seconds``.

    Raises
    ------
    ValueError, OSError, FileFormatError, MemoryError
        As :func:`spsr.reconstruct`, from whichever task met the problem; no output is
        written and the job folder is removed.
    """
    start = time.perf_counter()
    params = dict(params)
    trim_json = _trim_json(params)
    params_json = _params_json(params)
    paths = _paths(inputs)
    out = os.path.abspath(os.fspath(output))
    folder_parent = os.path.abspath(os.fspath(work_dir)) if work_dir else os.path.dirname(out)
    if slabs is not None and (isinstance(slabs, bool) or int(slabs) != slabs or slabs < 1):
        raise ValueError(f"invalid parameter slabs={slabs!r}: expected an integer of at least 1")
    if threads is not None and (isinstance(threads, bool) or threads < 1):
        raise ValueError(f"invalid parameter threads={threads!r}: expected an integer of at least 1")

    own_cluster = None
    if client is None:
        d = _distributed()
        own_cluster = d.LocalCluster(
            n_workers=os.cpu_count() or 1, threads_per_worker=1, processes=True
        )
        client = d.Client(own_cluster)
        if threads is None:
            threads = 1  # one worker per core already
    try:
        if slabs is None:
            slabs = 2 * max(1, len(client.scheduler_info()["workers"]))
        stats = _run(
            client, paths, out, folder_parent, int(slabs), params_json, threads, _fault, trim_json
        )
    finally:
        if own_cluster is not None:
            client.close()
            own_cluster.close()
    stats["seconds"] = time.perf_counter() - start
    for w in stats.get("warnings", []):
        warnings.warn(w, RuntimeWarning, stacklevel=2)
    return stats


def _run(
    client: Any,
    inputs: List[str],
    output: str,
    work_dir: str,
    slabs: int,
    params: str,
    threads: Optional[int],
    fault: Optional[Tuple[str, int, str]],
    trim: Optional[str] = None,
) -> Dict[str, Any]:
    token = uuid.uuid4().hex[:12]
    start = time.perf_counter()
    prepared = client.submit(
        _prepare_task,
        inputs,
        work_dir,
        slabs,
        params,
        threads,
        trim,
        key=f"spsr-prepare-{token}",
    )
    folder, k, noise, cycles = _settle(client, [prepared])[0]
    timings = [("prepare", time.perf_counter() - start)]
    try:
        timings += _run_steps(client, folder, k, noise, cycles, token, threads, fault)
        start = time.perf_counter()
        finish = client.submit(_finish_task, folder, output, key=f"spsr-finish-{token}")
        stats = dict(_settle(client, [finish])[0])
        stats["timings"] = timings + [("finish", time.perf_counter() - start)]
        return stats
    finally:
        _remove(client, folder, token)


def _remove(client: Any, folder: str, token: str) -> None:
    """Deletes the job folder: on a worker, or here when the cluster is gone."""
    try:
        client.submit(_remove_task, folder, key=f"spsr-remove-{token}").result()
        return
    except Exception:
        pass
    try:
        if os.path.isdir(folder):
            _spsr.slab_remove(folder)
    except Exception as e:
        warnings.warn(
            f"could not remove the job folder {folder}: {e}; delete it by hand",
            RuntimeWarning,
            stacklevel=3,
        )


# --------------------------------------------------------------------------------------
# python -m spsr.distributed

_USAGE = """\
usage: python -m spsr.distributed [--scheduler ADDRESS | --workers N] INPUT... -o OUTPUT.ply
                                  [spsr reconstruct's flags]

Runs `spsr reconstruct --slabs K` on a Dask cluster: each slab's work is a task.

  --scheduler ADDRESS  the Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: a local cluster)
  --workers N          the local cluster's worker processes (default: one per core)
  --slabs K            the number of slabs (default: twice the number of workers)
  --work-dir DIR       where the job folder goes; every worker must reach it at this path
                       (default: the output's folder)

The input files, the output and the work folder must be at the same paths on every worker.
Exit codes as spsr's, and 4 when the cluster failed (scheduler unreachable, a task's
workers kept dying).

spsr reconstruct's flags:
"""


def _own_flags(argv: List[str]) -> Tuple[Optional[str], Optional[int], List[str]]:
    """Takes --scheduler and --workers out of `argv`; the rest is spsr reconstruct's."""
    scheduler: Optional[str] = None
    workers: Optional[int] = None
    rest: List[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        name, eq, value = a.partition("=")
        if name in ("--scheduler", "--workers"):
            if not eq:
                if i + 1 >= len(argv):
                    raise ValueError(f"{name} needs a value")
                value = argv[i + 1]
                i += 1
            if name == "--scheduler":
                scheduler = value
            else:
                try:
                    workers = int(value)
                except ValueError:
                    workers = 0
                if workers < 1:
                    raise ValueError(f"--workers {value}: expected an integer of at least 1")
        else:
            rest.append(a)
        i += 1
    if scheduler is not None and workers is not None:
        raise ValueError("--scheduler and --workers cannot be used together")
    return scheduler, workers, rest


def _exit_code(e: BaseException) -> int:
    if isinstance(e, MemoryError):
        return 3
    if isinstance(e, FileFormatError):
        return 1
    if isinstance(e, ValueError):
        return 2
    if isinstance(e, OSError):
        return 1
    return 4


def _flag_refusal(params: str) -> Optional[str]:
    """Why a cluster cannot run the command line's parameters (as JSON), checked before a
    cluster starts; None when it can."""
    import json

    p = json.loads(params)
    resolution = p.get("resolution", "Depth")
    if isinstance(resolution, dict) and "Width" in resolution:
        return f"--width is not supported on a cluster: {_WHOLE_CLOUD}; give --depth D instead"
    if resolution == "Auto":
        return f"--depth auto is not supported on a cluster: {_WHOLE_CLOUD}; give --depth D instead"
    if p.get("grid_res") is not None:
        return f"--grid is not supported on a cluster: {_DEFAULT_ONLY['grid_res']}"
    return None


def main(argv: Optional[List[str]] = None) -> int:
    """The command line; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if any(a in ("-h", "--help") for a in argv):
        sys.stdout.write(_USAGE)
        sys.stdout.flush()
        return int(_spsr.slab_args(["python -m spsr.distributed", "--help"]))
    try:
        scheduler, workers, rest = _own_flags(argv)
    except ValueError as e:
        print(f"spsr: error: {e}", file=sys.stderr)
        return 2
    run = _spsr.slab_args(["python -m spsr.distributed", *rest])
    if isinstance(run, int):
        return run
    refusal = _flag_refusal(run["params"])
    if refusal is not None:
        print(f"spsr: error: {refusal}", file=sys.stderr)
        return 2
    d = _distributed()
    start = time.perf_counter()
    cluster = None
    try:
        if scheduler is None:
            cluster = d.LocalCluster(
                n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True
            )
            client = d.Client(cluster)
            if run["threads"] is None:
                run["threads"] = 1  # one worker per core already
        else:
            client = d.Client(scheduler, timeout="30s")
    except Exception as e:
        print(f"spsr: error: cannot reach the cluster: {e}", file=sys.stderr)
        return 4
    try:
        n_workers = len(client.scheduler_info()["workers"])
        slabs = run["slabs"] or 2 * max(1, n_workers)
        output = os.fspath(run["output"])
        stats = _run(
            client,
            _paths(run["inputs"]),
            os.path.abspath(output),
            os.path.abspath(os.fspath(run["work_dir"])),
            slabs,
            run["params"],
            run["threads"],
            None,
            run["trim"],
        )
    except Exception as e:
        print(f"spsr: error: {e}", file=sys.stderr)
        return _exit_code(e)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    for w in stats["warnings"]:
        print(f"spsr: warning: {w}", file=sys.stderr)
    if run["verbose"]:
        print(
            f"slabs       {stats['slabs']}\nworkers     {n_workers}\n"
            f"points      {stats['points']} read, {stats['dropped']} dropped\n"
            f"samples     {stats['samples']}\niso-value   {stats['iso_value']}\ntimings:",
            file=sys.stderr,
        )
        for step, seconds in stats["timings"]:
            print(f"  {step:<32} {seconds:10.3f} s", file=sys.stderr)
    closed = "closed" if stats["closed"] else f"open ({stats['open_edges']} edges without a partner)"
    pieces = stats["pieces"]
    print(
        f"spsr: wrote {output}: {stats['vertices']} vertices, {stats['faces']} faces, "
        f"{pieces} piece{'' if pieces == 1 else 's'}, {closed}, in {stats['slabs']} slabs on "
        f"{n_workers} worker{'' if n_workers == 1 else 's'}, in {time.perf_counter() - start:.2f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
