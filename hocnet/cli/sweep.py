"""``hocnet sweep dpa|train``: parameter grids and training configs on Ray Tune (sweep extra).

Layout of ``--out DIR``: ``DIR/sweep.json`` (what was swept: kind, grid, fixed settings),
``DIR/ray/NAME/`` (Ray Tune's experiment folder, which makes the sweep resumable) and
``DIR/results.csv`` (one row per trial: the grid point, its metrics, ``trial_id``, ``status``).
A new sweep refuses a ``DIR`` that already holds one unless ``--force`` (which replaces it);
``--resume`` continues the stored sweep (grid and settings from ``sweep.json``; finished trials
are not rerun) and rewrites its ``results.csv`` (only if hocnet wrote it and nobody changed it
since: see ``DIR/.hocnet-outputs.json``, :func:`hocnet.cli._common._foreign_files`).

Every argument is checked, and ``--address`` probed, before ``DIR`` is created; a sweep that
fails before its Ray experiment exists leaves nothing behind (the folders it created are
removed).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import socket
import textwrap
from pathlib import Path
from typing import Any

from hocnet.cli._common import (
    CLIError,
    _check_int,
    _check_number,
    _check_out_dir,
    _forget_outputs,
    _Formatter,
    _refuse_foreign,
    _table,
    _write_outputs,
)

SETTINGS_FILE = "sweep.json"
RESULTS_FILE = "results.csv"
RAY_FOLDER = "ray"


def _wrap(text: str) -> str:
    """Wrap each paragraph of a description (the formatter keeps line breaks as given)."""
    return "\n\n".join(
        textwrap.fill(p, 88, break_on_hyphens=False, break_long_words=False)
        for p in text.split("\n\n")
    )


def _require_ray() -> None:
    from hocnet.sweep import RayMissingError, require_ray

    try:
        require_ray()
    except RayMissingError as err:
        raise CLIError(f"sweep: {err}") from None


#: Seconds to wait for a TCP connection to --address before giving up. Ray 2.60 itself has no
#: overall timeout for ``ray.init(address=...)``: its per-attempt timeouts
#: (``RAY_gcs_rpc_server_connect_timeout_s``, 5 s) only bound each of its retries, which go on
#: for minutes against an address where nothing listens; hence this probe.
ADDRESS_TIMEOUT = 5.0

_LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _probe_address(address: str) -> None:
    """Refuse an ``--address`` that cannot be a running Ray cluster, within seconds.

    ``auto`` (and ``local``) are left to Ray; ``HOST:PORT`` and ``ray://HOST:PORT`` must name a
    port that accepts a TCP connection within :data:`ADDRESS_TIMEOUT` seconds.
    """
    text = address.strip()
    if text in ("auto", "local"):
        return
    rest = text.split("://", 1)[1] if "://" in text else text
    host, sep, port_text = rest.rstrip("/").rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise CLIError(f"--address: expected 'auto', HOST:PORT or ray://HOST:PORT, got {address!r}")
    hosts = [host]
    if host in _LOOPBACK:  # Ray connects a loopback address through the node's own IP
        with contextlib.suppress(Exception):
            from ray.util import get_node_ip_address

            hosts.append(get_node_ip_address())
    reason = "unreachable"
    for candidate in hosts:
        try:
            with socket.create_connection((candidate, int(port_text)), timeout=ADDRESS_TIMEOUT):
                return
        except OSError as err:
            if candidate == host:
                reason = "timed out" if isinstance(err, TimeoutError) else err.strerror or str(err)
    raise CLIError(
        f"--address: no Ray cluster reachable at {text} ({reason}); start one with "
        "'ray start --head' or leave out --address for a local instance"
    )


def _check_run_options(args: argparse.Namespace) -> None:
    """Check the run options before anything is created (the library checks them again)."""
    if args.num_cpus is not None:
        _check_int("--num-cpus", args.num_cpus, minimum=1)
    _check_number("--cpus-per-trial", args.cpus_per_trial, low=0.0, low_inclusive=False)
    if args.max_concurrent is not None:
        _check_int("--max-concurrent", args.max_concurrent, minimum=1)
    if args.address is not None:
        _probe_address(args.address)


def _made_by_us(out: Path) -> Path | None:
    """The outermost folder of ``out`` (itself or a parent) that does not exist yet."""
    created = None
    for parent in [out.absolute(), *out.absolute().parents]:
        if parent.exists():
            break
        created = parent
    return created


def _value(text: str) -> Any:
    """A grid value typed from its text: int, float, true/false, none, else the string."""
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    if low == "none":
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text.strip()


def _assignments(items: list[str] | None, flag: str, *, many: bool) -> dict[str, Any]:
    """``KEY=V1,V2`` (``many``: a list of values) or ``KEY=V`` (``V1,V2``: a tuple) -> dict."""
    out: dict[str, Any] = {}
    for item in items or []:
        key, sep, text = item.partition("=")
        if not sep or not key.strip() or not text.strip():
            raise CLIError(f"{flag}: expected KEY=VALUE{'S' if many else ''}, got {item!r}")
        key = key.strip()
        if many:
            out[key] = [_value(v) for v in text.split(",")]
        elif "," in text:
            out[key] = tuple(_value(v) for v in text.split(","))
        else:
            out[key] = _value(text)
    return out


def _paths(args: argparse.Namespace) -> tuple[Path, Path]:
    out = _check_out_dir(args.out)
    name = args.name.strip()
    if not name or "/" in name or name in (".", ".."):
        raise CLIError(f"--name: expected a folder name, got {args.name!r}")
    return out, out / RAY_FOLDER / name


def _stored(out: Path, kind: str) -> dict[str, Any]:
    path = out / SETTINGS_FILE
    if not path.is_file():
        raise CLIError(f"--resume: '{path}' does not exist: no sweep to resume in '{out}'")
    try:
        stored = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise CLIError(f"--resume: cannot read '{path}': {err}") from None
    if stored.get("kind") != kind:
        raise CLIError(f"--resume: '{path}' holds a {stored.get('kind')!r} sweep, not {kind!r}")
    return stored


def _prepare_new(out: Path, experiment: Path, force: bool) -> None:
    existing = [p for p in (out / SETTINGS_FILE, out / RESULTS_FILE, experiment) if p.exists()]
    if existing and not force:
        raise CLIError(
            f"--out: '{existing[0]}' exists: pass --resume to continue that sweep or --force "
            "to replace it"
        )


#: The hint of the refusal to rewrite a ``results.csv`` that hocnet did not write.
_RESUME_HINT = (
    "--resume rewrites it: move {it} away (or choose the sweep's own --out) and resume again"
)


def _run(args: argparse.Namespace, kind: str, build: Any) -> int:
    """Shared flow: check, store the settings, run on Ray, write ``results.csv``, summarise."""
    _require_ray()
    from hocnet.sweep import run_sweep, write_rows_csv

    out, experiment = _paths(args)
    if args.resume:
        if args.force:
            raise CLIError("--force: not with --resume (which keeps the finished trials)")
        stored = _stored(out, kind)
        if not experiment.is_dir():
            raise CLIError(f"--resume: no Ray experiment '{experiment}' to resume")
        _refuse_foreign(out, [RESULTS_FILE], _RESUME_HINT)
    else:
        stored = None
    trainable, space, settings, record = build(stored)
    if stored is None:
        _prepare_new(out, experiment, args.force)
    _check_run_options(args)  # every argument is checked before anything is created
    created = _made_by_us(out)
    try:
        if stored is None:
            if experiment.exists():  # --force: the previous sweep goes
                shutil.rmtree(experiment)
            text = json.dumps(record, indent=2, sort_keys=True) + "\n"
            writer = {SETTINGS_FILE: lambda path: path.write_text(text)}
            _write_outputs(out, writer, force=args.force)
        result = run_sweep(
            trainable,
            space,
            experiment,
            settings=settings,
            resume=args.resume,
            address=args.address,
            num_cpus=args.num_cpus,
            cpus_per_trial=args.cpus_per_trial,
            max_concurrent=args.max_concurrent,
            quiet=args.quiet,
        )
    except ValueError as err:
        _forget(out, experiment, stored, created)
        raise CLIError(str(err)) from None
    except BaseException:  # e.g. no Ray cluster at --address: leave no half-made sweep behind
        _forget(out, experiment, stored, created)
        raise
    writers = {RESULTS_FILE: lambda path: write_rows_csv(result.rows, path)}
    # a new sweep checked results.csv in _prepare_new, a resume before it ran
    (csv_path,) = _write_outputs(out, writers, force=args.force)
    _summary(result, csv_path, args.metric)
    if result.errors or result.done < len(result.rows):
        print(
            f"hocnet sweep: {len(result.rows) - result.done} of {len(result.rows)} trials did "
            f"not finish; rerun with --resume --out {args.out} to run them"
        )
        return 1
    return 0


def _forget(
    out: Path, experiment: Path, stored: dict[str, Any] | None, created: Path | None
) -> None:
    """Undo a new sweep whose Ray experiment never started.

    The folders this run created (``created``: ``out`` or a parent of it) are removed; in a
    folder that existed before, only the ``sweep.json`` written now and an empty ``ray/``. A
    sweep whose experiment exists is kept: it can be resumed.
    """
    if stored is not None or experiment.exists():
        return
    if created is not None:
        shutil.rmtree(created, ignore_errors=True)
        return
    (out / SETTINGS_FILE).unlink(missing_ok=True)
    _forget_outputs(out, [SETTINGS_FILE])
    with_ray = out / RAY_FOLDER
    if with_ray.is_dir() and not any(with_ray.iterdir()):
        with_ray.rmdir()


def _summary(result: Any, csv_path: Path, metric: str) -> None:
    rows = result.rows
    print(
        f"{len(rows)} trials ({result.done} done, {result.errors} errors) in "
        f"{result.seconds:.1f} s; results: {csv_path}"
    )
    scored = [r for r in rows if isinstance(r.get(metric), (int, float)) and r[metric] == r[metric]]
    if not scored:
        return
    best = sorted(scored, key=lambda r: r[metric], reverse=True)[:5]
    keys = [k for k in rows[0] if k not in ("trial_id", "status", "error")]
    body = [[r["trial_id"], *(_cell(r.get(k)) for k in keys)] for r in best]
    print(f"best {len(best)} by {metric}:")
    print(_table(["trial", *keys], body))


def _cell(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


# --------------------------------------------------------------------------------------------
# hocnet sweep dpa
# --------------------------------------------------------------------------------------------

_DPA_SETTINGS = (
    "scene",
    "shape",
    "scenes",
    "snr_db",
    "speed",
    "clouds",
    "window",
    "v_max",
    "p",
    "whiten",
    "pfa",
    "last",
    "block",
    "radius",
    "direction_step",
)


def _cmd_dpa(args: argparse.Namespace) -> int:
    def build(stored: dict[str, Any] | None) -> tuple[Any, ...]:
        from hocnet.sweep import DPASweepSettings, check_dpa_axes, dpa_param_space, dpa_trial

        if stored is None:
            axes = {
                "b": args.b,
                "g": args.g,
                "penalty_step": args.penalty_step,
                "s_n": args.s_n,
                "max_numbers": args.max_numbers,
                "seed": args.seeds,
            }
            fixed = {name: getattr(args, name) for name in _DPA_SETTINGS}
            fixed["shape"] = tuple(fixed["shape"])
            if fixed["block"] is not None:
                fixed["block"] = (
                    fixed["block"][0] if len(fixed["block"]) == 1 else tuple(fixed["block"])
                )
        else:
            axes, fixed = stored["grid"], stored["settings"]
            fixed["shape"] = tuple(fixed["shape"])
            if isinstance(fixed.get("block"), list):
                fixed["block"] = tuple(fixed["block"])
        settings = DPASweepSettings(**fixed)
        axes = check_dpa_axes(axes)
        record = {"kind": "dpa", "grid": axes, "settings": settings.to_dict()}
        return dpa_trial, dpa_param_space(**axes), settings, record

    return _run(args, "dpa", build)


def _add_run_options(parser: argparse.ArgumentParser, kind: str, metric: str) -> None:
    run = parser.add_argument_group("run")
    run.add_argument("--out", default=f"sweeps/{kind}", help="sweep folder (default: %(default)s)")
    run.add_argument("--name", default=kind, help="Ray experiment name (default: %(default)s)")
    run.add_argument(
        "--address",
        default=None,
        help="join a running Ray cluster ('auto', HOST:PORT or ray://HOST:PORT; an unreachable "
        "HOST:PORT is refused after at most 5 s, 'auto' is left to Ray); default: start an "
        "embedded local instance",
    )
    run.add_argument(
        "--num-cpus", type=int, default=None, help="CPUs of the local instance (default: all)"
    )
    run.add_argument(
        "--cpus-per-trial", type=float, default=1.0, help="CPUs per trial (default: 1)"
    )
    run.add_argument(
        "--max-concurrent", type=int, default=None, help="at most this many trials at a time"
    )
    run.add_argument(
        "--resume", action="store_true", help="continue the sweep in --out (finished trials kept)"
    )
    run.add_argument("--force", action="store_true", help="replace a sweep already in --out")
    run.add_argument("--quiet", action="store_true", help="no Ray progress table or worker logs")
    run.add_argument(
        "--metric", default=metric, help="metric of the best-trials table (default: %(default)s)"
    )


def _add_dpa(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dpa",
        help="a grid over the DPA's b, g, penalty step, s_n, Max_Numbers and seeds",
        description=_wrap(
            "Grid sweep of the DPA of [NR08] on simulated IR scenes. Every combination "
            "of the grid values is one trial; each reports A_S (eq. 16-17, paper reading), Pd at "
            "the per-pixel --pfa in the last frame (thresholds from the target-free twins of the "
            "same scenes), the back-tracking success rate, and valid = 0 (metrics NaN) when b is "
            "above the memory range of eq. (12)-(14).\n\n"
            "Example: hocnet sweep dpa --b 0.4 0.8 --g 0 1 --scene na23a --shape 8 45 45"
        ),
        formatter_class=_Formatter,
    )
    grid = p.add_argument_group("grid (every combination is one trial)")
    grid.add_argument(
        "--b", type=float, nargs="+", default=[0.8], help="memory factors b (default 0.8)"
    )
    grid.add_argument(
        "--g", type=float, nargs="+", default=[1.0], help="sum/max mixing g (default 1)"
    )
    grid.add_argument(
        "--penalty-step",
        type=float,
        nargs="+",
        default=[3.0],
        help="penalty step x of W_penalty, in [0, 3] (default 3)",
    )
    grid.add_argument(
        "--s-n", type=int, nargs="+", default=[1], help="frame sampling s_n (default 1)"
    )
    grid.add_argument(
        "--max-numbers",
        type=int,
        nargs="+",
        default=[1],
        help="Max_Numbers of eq. (16) (default 1)",
    )
    grid.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[0],
        help="scene seeds, one batch of --scenes each (default 0)",
    )
    fixed = p.add_argument_group("scenes and metrics (the same in every trial)")
    fixed.add_argument("--scene", default="na23a", help="na23a, npa or ir (default na23a)")
    fixed.add_argument(
        "--shape",
        type=int,
        nargs=3,
        default=[10, 45, 45],
        metavar=("T", "H", "W"),
        help="frames seen by the DPA, after sampling (default 10 45 45)",
    )
    fixed.add_argument("--scenes", type=int, default=2, help="scenes per trial (default 2)")
    fixed.add_argument("--snr-db", type=float, default=None, help="peak SNR (default: preset)")
    fixed.add_argument("--speed", type=float, default=None, help="px/frame (default: preset)")
    fixed.add_argument("--clouds", default=None, help="clear, wispy or bright (na23a, ir)")
    fixed.add_argument("--window", type=int, default=5, help="matrix size (default 5)")
    fixed.add_argument("--v-max", type=float, default=1.0, help="W_frame speed (default 1)")
    fixed.add_argument("--p", type=float, default=0.5, help="W_basic weight p (default 0.5)")
    fixed.add_argument("--whiten", default="anti_mean", help="anti_mean or anti_median")
    fixed.add_argument("--pfa", type=float, default=1e-3, help="per-pixel Pfa of pd")
    fixed.add_argument("--last", type=int, default=6, help="frames averaged by A_S")
    fixed.add_argument(
        "--block", type=int, nargs="+", default=None, help="A_S block: SIZE or ROWS COLS"
    )
    fixed.add_argument("--radius", type=float, default=1.5, help="hit radius (px)")
    fixed.add_argument(
        "--direction-step", default="paper", help="paper (eq. 7-8) or source (default paper)"
    )
    _add_run_options(p, "dpa", "a_s")
    p.set_defaults(func=_cmd_dpa)


# --------------------------------------------------------------------------------------------
# hocnet sweep train
# --------------------------------------------------------------------------------------------


def _cmd_train(args: argparse.Namespace) -> int:
    def build(stored: dict[str, Any] | None) -> tuple[Any, ...]:
        import importlib.util

        if importlib.util.find_spec("lightning") is None:
            raise CLIError(
                "sweep train: needs the learn extra (Lightning, torchmetrics): "
                "pip install 'hocnet[learn,sweep]'"
            )
        from hocnet.learn.sweep import (
            TrainSweepSettings,
            check_train_config,
            train_param_space,
            train_trial,
        )

        if stored is None:
            grid = _assignments(args.grid, "--grid", many=True)
            if not grid:
                raise CLIError("--grid: expected at least one KEY=V1,V2 axis, got none")
            fixed = {
                "system": args.system,
                "max_epochs": args.max_epochs,
                "fixed": _assignments(args.set, "--set", many=False),
                "seed": args.seed,
                "fast_dev_run": args.fast_dev_run,
            }
        else:
            grid, fixed = stored["grid"], stored["settings"]
        settings = TrainSweepSettings(**fixed)
        check_train_config({k: v[0] for k, v in grid.items()}, settings)
        record = {"kind": "train", "grid": grid, "settings": settings.to_dict()}
        return train_trial, train_param_space(grid), settings, record

    return _run(args, "train", build)


def _add_train(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train",
        help="training runs (hocnet train dpa|hoc) over a grid of configs",
        description=_wrap(
            "One Lightning training run per grid point (the options of `hocnet train "
            "SYSTEM --help`, as model.NAME / data.NAME keys); each trial reports its test "
            "metrics.\n\nExample: hocnet sweep train dpa --grid model.lr=0.01,0.05 "
            "--set data.n_train=8 --max-epochs 2"
        ),
        formatter_class=_Formatter,
    )
    p.add_argument("system", choices=("dpa", "hoc"), help="DPATuner or LearnedHOCSystem")
    p.add_argument(
        "--grid",
        action="append",
        metavar="KEY=V1,V2",
        help="a grid axis, e.g. model.lr=0.01,0.05 (repeatable)",
    )
    p.add_argument(
        "--set", action="append", metavar="KEY=V", help="a fixed option, e.g. data.n_train=8"
    )
    p.add_argument("--max-epochs", type=int, default=2, help="epochs per trial (default 2)")
    p.add_argument("--seed", type=int, default=0, help="seed_everything seed (default 0)")
    p.add_argument("--fast-dev-run", action="store_true", help="one batch per stage (smoke)")
    _add_run_options(p, "train", "test/pd")
    p.set_defaults(func=_cmd_train)


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Register ``sweep`` on the ``hocnet`` subcommand parser."""
    sweep = commands.add_parser(
        "sweep",
        help="parameter grids of the DPA and training runs over configs, on Ray Tune",
        description=_wrap(
            "Sweeps on Ray Tune (the sweep extra: pip install 'hocnet[sweep]'). "
            "An embedded local Ray instance is started unless --address joins a cluster; the "
            "sweep is resumable (--resume); results land in --out/results.csv."
        ),
        formatter_class=_Formatter,
    )
    sub = sweep.add_subparsers(dest="kind", metavar="KIND", required=True)
    _add_dpa(sub)
    _add_train(sub)
